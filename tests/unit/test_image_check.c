/* test_image_check.c - what is checked of an image before a decoder sees
 * it (image_check.c) and the GeoTIFF tag reader and writer (tiff_tags.c),
 * through their own C APIs. test_image.c covers the same code end to end
 * through ts_image_read; here each check meets hand-made bytes directly. */
#include <stdio.h>
#include <unistd.h>

#include "error.h"
#include "image_check.h"
#include "tiff_tags.h"
#include "ts_test.h"

/* --- fixtures ------------------------------------------------------------- */

static ts_image_src mem_src(const void *data, size_t len) {
  return (ts_image_src){"ref.img", NULL, data, len};
}

static const uint8_t kPngSig[8] = {0x89, 'P', 'N', 'G', 0x0d, 0x0a, 0x1a, 0x0a};
static const uint8_t kExrMagic[4] = {0x76, 0x2f, 0x31, 0x01};

/* Appends a PNG chunk claiming len bytes but holding have bytes (CRCs are
 * not judged by the size check). Returns the new size. */
static size_t png_chunk(uint8_t *buf, size_t n, const char type[4], uint32_t len, uint32_t have) {
  buf[n++] = (uint8_t)(len >> 24);
  buf[n++] = (uint8_t)(len >> 16);
  buf[n++] = (uint8_t)(len >> 8);
  buf[n++] = (uint8_t)len;
  memcpy(buf + n, type, 4);
  n += 4;
  memset(buf + n, 0, have + 4u);
  return n + have + 4;
}

/* An OpenEXR header attribute claiming size bytes and holding have. */
static size_t exr_attr(uint8_t *buf, size_t n, const char *name, int32_t size, uint32_t have) {
  size_t k = strlen(name) + 1;
  memcpy(buf + n, name, k);
  n += k;
  memcpy(buf + n, "int", 4);
  n += 4;
  uint32_t u = (uint32_t)size;
  for (int i = 0; i < 4; i++) buf[n++] = (uint8_t)(u >> (8 * i));
  memset(buf + n, 0, have);
  return n + have;
}

static size_t exr_start(uint8_t *buf) {
  memcpy(buf, kExrMagic, 4);
  buf[4] = 2, buf[5] = buf[6] = buf[7] = 0; /* version 2, single part */
  return 8;
}

/* --- ts_image_sniff --------------------------------------------------------- */

static void sniff_tells_the_four_formats(void **state) {
  (void)state;
  static const struct {
    uint8_t bytes[8];
    size_t n;
    const char *format;
  } cases[] = {
      {{0x89, 'P', 'N', 'G', 0x0d, 0x0a, 0x1a, 0x0a}, 8, "png"},
      {{0xff, 0xd8, 0xff, 0xe0}, 4, "jpeg"},
      {{'I', 'I', 42, 0, 8, 0, 0, 0}, 8, "tiff"},
      {{'M', 'M', 0, 42, 0, 0, 0, 8}, 8, "tiff"},
      {{'I', 'I', 43, 0, 8, 0, 0, 0}, 8, "tiff"},
      {{'M', 'M', 0, 43, 0, 8, 0, 0}, 8, "tiff"},
      {{0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0}, 8, "openexr"},
  };
  for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
    ts_image_src src = mem_src(cases[i].bytes, cases[i].n);
    const char *format = NULL;
    char err[TS_ERR_LEN];
    assert_int_equal(ts_image_sniff(&src, &format, err), 0);
    assert_string_equal(format, cases[i].format);
  }
}

/* ts_image_sniff refuses src with code and exactly message. */
static void assert_sniff_fails(ts_image_src src, int code, const char *message) {
  const char *format;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_image_sniff(&src, &format, err), code);
  assert_string_equal(err, message);
}

static void sniff_names_the_bytes_of_other_files(void **state) {
  (void)state;
  assert_sniff_fails(mem_src("GIF89a\x01\x00rest", 12), TS_EFORMAT,
                     "ref.img: not a PNG, JPEG, TIFF or OpenEXR image (starts with bytes "
                     "47 49 46 38 39 61 01 00)");
}

static void sniff_refuses_an_empty_file(void **state) {
  (void)state;
  assert_sniff_fails(mem_src("", 0), TS_EFORMAT, "ref.img: empty file (0 bytes), not an image");
}

static void sniff_names_a_missing_file(void **state) {
  (void)state;
  ts_image_src src = {"/nonexistent/ref.png", "/nonexistent/ref.png", NULL, 0};
  assert_sniff_fails(src, TS_ENOENT, "/nonexistent/ref.png: no such file");
}

static void sniff_refuses_a_directory(void **state) {
  (void)state;
  ts_image_src src = {"/tmp", "/tmp", NULL, 0};
  assert_sniff_fails(src, TS_EFORMAT, "/tmp: not a regular file");
}

/* --- ts_image_check_sizes: PNG ------------------------------------------------ */

/* ts_image_check_sizes on the n bytes at buf as format: its code, and its
 * message in err. */
static int check_sizes(const uint8_t *buf, size_t n, const char *format, char err[TS_ERR_LEN]) {
  ts_image_src src = mem_src(buf, n);
  return ts_image_check_sizes(&src, format, err);
}

static void png_sizes_pass_when_chunks_fit(void **state) {
  (void)state;
  uint8_t buf[128];
  memcpy(buf, kPngSig, 8);
  size_t n = png_chunk(buf, 8, "IHDR", 13, 13);
  n = png_chunk(buf, n, "IEND", 0, 0);
  char err[TS_ERR_LEN];
  assert_int_equal(check_sizes(buf, n, "png", err), 0);
}

static void png_chunk_over_the_file_is_refused(void **state) {
  (void)state;
  uint8_t buf[128];
  memcpy(buf, kPngSig, 8);
  size_t n = png_chunk(buf, 8, "IHDR", 13, 13);
  n = png_chunk(buf, n, "tEXt", 1800000000u, 10);
  char err[TS_ERR_LEN];
  assert_int_equal(check_sizes(buf, n, "png", err), TS_EFORMAT);
  assert_string_equal(err, "ref.img: unreadable or truncated image: chunk 'tEXt' claims 1800000000 "
                           "bytes, the file has 10 left");
}

static void png_chunk_name_is_shown_escaped(void **state) {
  (void)state;
  uint8_t buf[64];
  memcpy(buf, kPngSig, 8);
  size_t n = png_chunk(buf, 8, "\x00\\a\x7f", 0x80000000u, 0);
  char err[TS_ERR_LEN];
  assert_int_equal(check_sizes(buf, n, "png", err), TS_EFORMAT);
  assert_non_null(strstr(err, "chunk '\\x00\\x5ca\\x7f' claims 2147483648 bytes"));
}

static void png_cut_short_is_refused(void **state) {
  (void)state;
  uint8_t buf[128];
  memcpy(buf, kPngSig, 8);
  size_t n = png_chunk(buf, 8, "IHDR", 13, 13);
  char err[TS_ERR_LEN];
  assert_int_equal(check_sizes(buf, n, "png", err), TS_EFORMAT); /* no IEND */
  assert_string_equal(err, "ref.img: unreadable or truncated image: no IEND chunk");
  memset(buf + n, 0, 5); /* five bytes of a next chunk header */
  assert_int_equal(check_sizes(buf, n + 5, "png", err), TS_EFORMAT);
  assert_string_equal(err, "ref.img: unreadable or truncated image: file ends inside a chunk header");
}

/* --- ts_image_check_sizes: OpenEXR --------------------------------------------- */

static void exr_sizes_pass_when_attributes_fit(void **state) {
  (void)state;
  uint8_t buf[128];
  size_t n = exr_start(buf);
  n = exr_attr(buf, n, "lineOrder", 1, 1);
  n = exr_attr(buf, n, "x", 4, 4);
  buf[n++] = 0; /* end of the header */
  char err[TS_ERR_LEN];
  assert_int_equal(check_sizes(buf, n, "openexr", err), 0);
}

static void exr_attribute_over_the_file_is_refused(void **state) {
  (void)state;
  uint8_t buf[128];
  size_t n = exr_start(buf);
  n = exr_attr(buf, n, "comments", 1200000000, 3);
  char err[TS_ERR_LEN];
  assert_int_equal(check_sizes(buf, n, "openexr", err), TS_EFORMAT);
  assert_string_equal(err, "ref.img: not a readable openexr image: header attribute 'comments' claims "
                           "1200000000 bytes, more than the file holds");
  n = exr_start(buf);
  n = exr_attr(buf, n, "neg", -1, 0);
  assert_int_equal(check_sizes(buf, n, "openexr", err), TS_EFORMAT);
  assert_non_null(strstr(err, "'neg' claims -1 bytes"));
}

static void exr_long_name_is_refused(void **state) {
  (void)state;
  uint8_t buf[512];
  size_t n = exr_start(buf);
  memset(buf + n, 'a', 256);
  buf[n + 256] = 0;
  char err[TS_ERR_LEN];
  assert_int_equal(check_sizes(buf, n + 257, "openexr", err), TS_EFORMAT);
  assert_string_equal(err, "ref.img: not a readable openexr image: header attribute name over 255 bytes");
  buf[n + 255] = 0; /* 255 bytes are fine: then it is cut short */
  assert_int_equal(check_sizes(buf, n + 256, "openexr", err), TS_EFORMAT);
  assert_string_equal(err, "ref.img: not a readable openexr image: header cut short");
}

static void other_formats_pass_the_size_check(void **state) {
  (void)state;
  static const uint8_t jpeg[] = {0xff, 0xd8, 0xff, 'g', 'a', 'r', 'b', 'a', 'g', 'e'};
  char err[TS_ERR_LEN];
  assert_int_equal(check_sizes(jpeg, sizeof(jpeg), "jpeg", err), 0);
  assert_int_equal(check_sizes(jpeg, sizeof(jpeg), "tiff", err), 0);
}

/* --- GeoTIFF tags ------------------------------------------------------------------ */

/* One directory entry of a hand-made TIFF: values in host order. */
typedef struct {
  uint16_t tag, type;
  uint32_t count;
  const void *values;
} tt_entry;

static size_t tt_size(uint16_t type) { return type == TS_TIFF_DOUBLE ? 8 : type == TS_TIFF_SHORT ? 2 : 1; }

static void tt_put(uint8_t *p, int be, size_t n, uint64_t v) {
  for (size_t i = 0; i < n; i++) p[be ? n - 1 - i : i] = (uint8_t)(v >> (8 * i));
}

/* The values of e in the file's byte order at p. */
static void tt_values(uint8_t *p, int be, const tt_entry *e) {
  size_t size = tt_size(e->type);
  for (uint32_t i = 0; i < e->count; i++) {
    uint64_t v = 0;
    if (size == 8) memcpy(&v, (const uint8_t *)e->values + 8 * i, 8);
    else if (size == 2) v = ((const uint16_t *)e->values)[i];
    else v = ((const uint8_t *)e->values)[i];
    tt_put(p + size * i, be, size, v);
  }
}

/* A TIFF holding only a first directory of these entries (no pixels: the
 * tag code never looks at them). Returns its size. */
static size_t tt_build(uint8_t *buf, int be, int big, const tt_entry *e, size_t n) {
  size_t word = big ? 8 : 4, esz = big ? 20 : 12, cw = big ? 8 : 2;
  memset(buf, 0, 4096);
  buf[0] = buf[1] = be ? 'M' : 'I';
  tt_put(buf + 2, be, 2, big ? 43 : 42);
  size_t ifd = big ? 16 : 8;
  if (big) {
    tt_put(buf + 4, be, 2, 8);
    tt_put(buf + 8, be, 8, ifd);
  } else {
    tt_put(buf + 4, be, 4, ifd);
  }
  tt_put(buf + ifd, be, cw, n);
  size_t pos = ifd + cw + n * esz + word;
  for (size_t i = 0; i < n; i++) {
    uint8_t *d = buf + ifd + cw + i * esz;
    tt_put(d, be, 2, e[i].tag);
    tt_put(d + 2, be, 2, e[i].type);
    tt_put(d + 4, be, word, e[i].count);
    size_t bytes = e[i].count * tt_size(e[i].type);
    if (bytes <= word) {
      tt_values(d + 4 + word, be, &e[i]);
    } else {
      tt_put(d + 4 + word, be, word, pos);
      tt_values(buf + pos, be, &e[i]);
      pos += (bytes + 1) & ~(size_t)1;
    }
  }
  return pos;
}

static const double kScale[3] = {0.5, 0.25, 0.0};
static const uint16_t kKeys[8] = {1, 1, 0, 1, 1024, 0, 1, 1};
static const char kAscii[] = "WGS 84|";
static const uint16_t kWidth[1] = {4};

static const tt_entry kGeoEntries[] = {
    {256, TS_TIFF_SHORT, 1, kWidth}, /* ImageWidth: not ours */
    {33550, TS_TIFF_DOUBLE, 3, kScale},
    {34735, TS_TIFF_SHORT, 8, kKeys},
    {34737, TS_TIFF_ASCII, sizeof(kAscii), kAscii},
    {42113, TS_TIFF_ASCII, 2, "0"}, /* inline */
};
#define N_GEO_ENTRIES (sizeof(kGeoEntries) / sizeof(kGeoEntries[0]))

/* Index of the GeoTIFF tag numbered tag in ts_geotags. */
static int geo_index(uint16_t tag) {
  for (int i = 0; i < TS_GEOTAG_COUNT; i++)
    if (ts_geotags[i].tag == tag) return i;
  fail_msg("tag %u is no GeoTIFF tag", tag);
  return -1;
}

static void geo_read_mem(const uint8_t *buf, size_t n, ts_geo_value tags[TS_GEOTAG_COUNT]) {
  FILE *f = fmemopen((void *)buf, n, "rb");
  assert_non_null(f);
  assert_int_equal(ts_geo_read(f, tags), 0);
  fclose(f);
}

/* tags hold exactly the GeoTIFF entries of kGeoEntries. */
static void assert_fixture_tags(const ts_geo_value tags[TS_GEOTAG_COUNT]) {
  int seen = 0;
  for (size_t i = 1; i < N_GEO_ENTRIES; i++) {
    const ts_geo_value *v = &tags[geo_index(kGeoEntries[i].tag)];
    assert_int_equal(v->count, kGeoEntries[i].count);
    assert_memory_equal(v->values, kGeoEntries[i].values, v->count * tt_size(kGeoEntries[i].type));
    seen++;
  }
  for (int i = 0; i < TS_GEOTAG_COUNT; i++) seen -= tags[i].values != NULL;
  assert_int_equal(seen, 0);
}

static void geotag_named_ignores_case(void **state) {
  (void)state;
  assert_ptr_equal(ts_geotag_named("geotiff:modelpixelscale"), &ts_geotags[0]);
  assert_int_equal(ts_geotag_named("GDAL:NODATA")->tag, 42113);
  assert_null(ts_geotag_named("GeoTIFF:Model"));
  assert_null(ts_geotag_named("ImageDescription"));
}

static void geo_read_gives_host_order_in_every_layout(void **state) {
  (void)state;
  for (int be = 0; be < 2; be++)
    for (int big = 0; big < 2; big++) {
      uint8_t buf[4096];
      size_t n = tt_build(buf, be, big, kGeoEntries, N_GEO_ENTRIES);
      ts_geo_value tags[TS_GEOTAG_COUNT];
      geo_read_mem(buf, n, tags);
      assert_fixture_tags(tags);
      ts_geo_free(tags);
    }
}

static void geo_read_of_a_non_tiff_finds_none(void **state) {
  (void)state;
  static const uint8_t png[16] = {0x89, 'P', 'N', 'G', 0x0d, 0x0a, 0x1a, 0x0a};
  ts_geo_value tags[TS_GEOTAG_COUNT];
  geo_read_mem(png, sizeof(png), tags);
  for (int i = 0; i < TS_GEOTAG_COUNT; i++) assert_null(tags[i].values);
}

static void geo_read_skips_a_tag_past_the_end(void **state) {
  (void)state;
  uint8_t buf[4096];
  size_t n = tt_build(buf, 0, 0, kGeoEntries, N_GEO_ENTRIES);
  /* Entry 2 (GeoKeyDirectory, 8 shorts at an offset): point past the end. */
  tt_put(buf + 8 + 2 + 2 * 12 + 8, 0, 4, n - 4);
  ts_geo_value tags[TS_GEOTAG_COUNT];
  geo_read_mem(buf, n, tags);
  assert_null(tags[geo_index(34735)].values);
  assert_non_null(tags[geo_index(33550)].values);
  ts_geo_free(tags);
}

static void geo_write_replaces_the_tags_in_every_layout(void **state) {
  (void)state;
  char path[32];
  ts_test_put_file(path, "", 0);
  static const double kOld[3] = {9, 9, 9};
  const tt_entry old[] = {{256, TS_TIFF_SHORT, 1, kWidth}, {33550, TS_TIFF_DOUBLE, 3, kOld}};
  for (int be = 0; be < 2; be++)
    for (int big = 0; big < 2; big++) {
      uint8_t buf[4096];
      size_t n = tt_build(buf, be, big, old, 2);
      FILE *f = fopen(path, "wb");
      assert_int_equal(fwrite(buf, 1, n, f), n);
      fclose(f);
      ts_geo_value tags[TS_GEOTAG_COUNT] = {{0, NULL}};
      for (size_t i = 1; i < N_GEO_ENTRIES; i++)
        tags[geo_index(kGeoEntries[i].tag)] = (ts_geo_value){kGeoEntries[i].count, kGeoEntries[i].values};
      char why[TS_ERR_LEN];
      assert_int_equal(ts_geo_write(path, tags, why), 0);
      f = fopen(path, "rb");
      ts_geo_value back[TS_GEOTAG_COUNT];
      assert_int_equal(ts_geo_read(f, back), 0);
      fclose(f);
      assert_fixture_tags(back); /* the old scale is gone, ours are there */
      ts_geo_free(back);
    }
  unlink(path);
}

static void geo_write_refuses_a_non_tiff(void **state) {
  (void)state;
  char path[32];
  ts_test_put_file(path, "not a tiff at all", 17);
  ts_geo_value tags[TS_GEOTAG_COUNT] = {{0, NULL}};
  char why[TS_ERR_LEN];
  assert_int_equal(ts_geo_write(path, tags, why), TS_EFORMAT);
  assert_string_equal(why, "cannot parse the TIFF directory to add GeoTIFF tags");
  unlink(path);
  assert_int_equal(ts_geo_write(path, tags, why), TS_EIO);
  assert_string_equal(why, "No such file or directory");
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(sniff_tells_the_four_formats),
    cmocka_unit_test(sniff_names_the_bytes_of_other_files),
    cmocka_unit_test(sniff_refuses_an_empty_file),
    cmocka_unit_test(sniff_names_a_missing_file),
    cmocka_unit_test(sniff_refuses_a_directory),
    cmocka_unit_test(png_sizes_pass_when_chunks_fit),
    cmocka_unit_test(png_chunk_over_the_file_is_refused),
    cmocka_unit_test(png_chunk_name_is_shown_escaped),
    cmocka_unit_test(png_cut_short_is_refused),
    cmocka_unit_test(exr_sizes_pass_when_attributes_fit),
    cmocka_unit_test(exr_attribute_over_the_file_is_refused),
    cmocka_unit_test(exr_long_name_is_refused),
    cmocka_unit_test(other_formats_pass_the_size_check),
    cmocka_unit_test(geotag_named_ignores_case),
    cmocka_unit_test(geo_read_gives_host_order_in_every_layout),
    cmocka_unit_test(geo_read_of_a_non_tiff_finds_none),
    cmocka_unit_test(geo_read_skips_a_tag_past_the_end),
    cmocka_unit_test(geo_write_replaces_the_tags_in_every_layout),
    cmocka_unit_test(geo_write_refuses_a_non_tiff),
};

TS_TEST_MAIN(tests)
