/* test_image.c - image files in and out (image_oiio.cpp) and the pixel
 * helpers (image.c). Every test works in its own mkdtemp directory, removed
 * afterwards. Fixtures that OpenImageIO cannot make for us (a GeoTIFF, a
 * TIFF with its directory before the pixels, huge headers) are written byte
 * by byte here, which also checks our reader against an independent
 * encoder rather than against our own writer. */
#include <dirent.h>
#include <limits.h>
#include <math.h>
#include <stdio.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include "error.h"
#include "image.h"
#include "image_meta.h"
#include "ts_test.h"
#include "util.h"

#if defined(__SANITIZE_ADDRESS__)
#define TS_ASAN 1
#else
#define TS_ASAN 0
#endif

/* --- fixture: a scratch directory per test ------------------------------ */

typedef struct {
  char dir[64];
} scratch;

static int scratch_setup(void **state) {
  scratch *s = calloc(1, sizeof(*s));
  if (s == NULL) return -1;
  snprintf(s->dir, sizeof(s->dir), "/tmp/ts-image-XXXXXX");
  if (mkdtemp(s->dir) == NULL) {
    free(s);
    return -1;
  }
  *state = s;
  return 0;
}

/* Removes the directory's entries (files, or the empty directories some
 * tests create) and the directory. */
static int scratch_teardown(void **state) {
  scratch *s = *state;
  DIR *d = opendir(s->dir);
  if (d != NULL) {
    struct dirent *e;
    while ((e = readdir(d)) != NULL) {
      if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0) continue;
      char p[PATH_MAX];
      snprintf(p, sizeof(p), "%s/%s", s->dir, e->d_name);
      if (unlink(p) != 0) rmdir(p);
    }
    closedir(d);
  }
  rmdir(s->dir);
  free(s);
  return 0;
}

static void path_of(void **state, const char *name, char *out) {
  snprintf(out, PATH_MAX, "%s/%s", ((scratch *)*state)->dir, name);
}

/* Number of entries in the scratch directory (to spot stray temp files). */
static int scratch_count(void **state) {
  DIR *d = opendir(((scratch *)*state)->dir);
  int n = 0;
  struct dirent *e;
  while ((e = readdir(d)) != NULL)
    if (strcmp(e->d_name, ".") != 0 && strcmp(e->d_name, "..") != 0) n++;
  closedir(d);
  return n;
}

/* --- helpers ------------------------------------------------------------- */

static void write_file(const char *path, const void *data, size_t n) {
  FILE *f = fopen(path, "wb");
  assert_non_null(f);
  assert_int_equal(fwrite(data, 1, n, f), n);
  assert_int_equal(fclose(f), 0);
}

static uint8_t *read_file(const char *path, size_t *n) {
  uint8_t *b;
  char err[TS_ERR_LEN];
  if (ts_file_read(path, SIZE_MAX, &b, n, err) != 0) fail_msg("%s", err);
  return b;
}

/* Copies the first `keep` bytes of src to dst. */
static void cut_file(const char *src, const char *dst, size_t keep) {
  size_t n;
  uint8_t *b = read_file(src, &n);
  assert_true(keep < n);
  write_file(dst, b, keep);
  free(b);
}

static size_t image_bytes(const ts_image *img) {
  return (size_t)img->width * img->height * img->channels * ts_pixtype_size(img->type);
}

/* A deterministic, busy pattern (so compressed files are not tiny). */
static void make_image(ts_image *img, int w, int h, int c, ts_pixtype t) {
  char err[TS_ERR_LEN];
  assert_int_equal(ts_image_alloc(img, w, h, c, t, err), 0);
  size_t n = (size_t)w * h * c;
  uint32_t r = 12345;
  for (size_t i = 0; i < n; i++) {
    r = r * 1103515245u + 12345u;
    uint32_t v = r >> 8;
    switch (t) {
    case TS_PIX_U8:
      ((uint8_t *)img->pixels)[i] = (uint8_t)v;
      break;
    case TS_PIX_U16:
      ((uint16_t *)img->pixels)[i] = (uint16_t)v;
      break;
    case TS_PIX_F16: /* finite halves of both signs: exponent field < 31 */
      ((uint16_t *)img->pixels)[i] = (uint16_t)((v & 0x83ff) | ((v >> 16) % 31) << 10);
      break;
    case TS_PIX_F32:
      ((float *)img->pixels)[i] = (float)((int32_t)(v & 0xffff) - 20000) / 777.0f;
      break;
    }
  }
}

/* A smooth colour gradient, friendly to JPEG. */
static void make_gradient(ts_image *img, int w, int h, int c) {
  char err[TS_ERR_LEN];
  assert_int_equal(ts_image_alloc(img, w, h, c, TS_PIX_U8, err), 0);
  uint8_t *p = img->pixels;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++)
      for (int k = 0; k < c; k++)
        *p++ = (uint8_t)(k == 0   ? x * 255 / (w - 1)
                         : k == 1 ? y * 255 / (h - 1)
                                  : (x + y) * 255 / (w + h - 2));
}

static void assert_same_image(const ts_image *a, const ts_image *b) {
  assert_int_equal(a->width, b->width);
  assert_int_equal(a->height, b->height);
  assert_int_equal(a->channels, b->channels);
  assert_int_equal(a->type, b->type);
  assert_memory_equal(a->pixels, b->pixels, image_bytes(a));
}

/* Writes img to name, reads it back, checks it is bit-identical. */
static void roundtrip_exact(void **state, const char *name, const ts_image *img) {
  char path[PATH_MAX], err[TS_ERR_LEN];
  ts_image back;
  path_of(state, name, path);
  assert_int_equal(ts_image_write(path, img, NULL, err), 0);
  assert_int_equal(ts_image_read(path, &back, NULL, err), 0);
  assert_same_image(img, &back);
  assert_non_null(back.meta);
  ts_image_free(&back);
}

/* Expects a read of path to fail with code, naming the file. */
static void expect_read_error(const char *path, int code) {
  char err[TS_ERR_LEN] = "";
  ts_image img;
  assert_int_equal(ts_image_read(path, &img, NULL, err), code);
  assert_null(img.pixels);
  assert_non_null(strstr(err, path));
  assert_null(strchr(err, '\n'));
  print_message("     err: %s\n", err);
}

/* --- a hand-made TIFF encoder (little-endian classic or BigTIFF) -------- */

enum { T_ASCII = 2, T_SHORT = 3, T_LONG = 4, T_DOUBLE = 12 };

typedef struct {
  uint16_t tag, type;
  uint32_t count;
  const void *data; /* little-endian values, count * size bytes */
} tt_entry;

static void le(uint8_t *p, uint64_t v, int n) {
  for (int i = 0; i < n; i++) p[i] = (uint8_t)(v >> (8 * i));
}

static int tt_size(uint16_t type) {
  return type == T_DOUBLE ? 8 : type == T_LONG ? 4 : type == T_SHORT ? 2 : 1;
}

/* Header, then the directory (entries sorted by the caller), then the
 * values that do not fit inline, then the pixels: the directory comes
 * first, so a cut in the pixels leaves a parseable header. Entries 273
 * (StripOffsets) get the pixel offset filled in. Returns the size. */
static size_t tt_build(uint8_t *buf, int big, const tt_entry *e, int n, const uint8_t *pix,
                       size_t pixlen) {
  int word = big ? 8 : 4, esz = big ? 20 : 12, cw = big ? 8 : 2;
  size_t ifd = big ? 16 : 8;
  size_t pos = ifd + cw + (size_t)n * esz + word;
  size_t pixpos = pos;
  for (int i = 0; i < n; i++) {
    size_t bytes = (size_t)e[i].count * tt_size(e[i].type);
    if (bytes > (size_t)word) pixpos += (bytes + 1) & ~(size_t)1;
  }
  memset(buf, 0, pixpos); /* padding included */
  memcpy(buf, "II", 2);
  le(buf + 2, big ? 43 : 42, 2);
  if (big) {
    le(buf + 4, 8, 2);
    le(buf + 6, 0, 2);
    le(buf + 8, ifd, 8);
  } else {
    le(buf + 4, ifd, 4);
  }
  le(buf + ifd, (uint64_t)n, cw);
  for (int i = 0; i < n; i++) {
    uint8_t *d = buf + ifd + cw + (size_t)i * esz;
    size_t bytes = (size_t)e[i].count * tt_size(e[i].type);
    le(d, e[i].tag, 2);
    le(d + 2, e[i].type, 2);
    le(d + 4, e[i].count, word);
    if (e[i].tag == 273) {
      le(d + 4 + word, pixpos, 4);
    } else if (bytes <= (size_t)word) {
      memcpy(d + 4 + word, e[i].data, bytes);
    } else {
      le(d + 4 + word, pos, word);
      memcpy(buf + pos, e[i].data, bytes);
      pos += (bytes + 1) & ~(size_t)1;
    }
  }
  le(buf + ifd + cw + (size_t)n * esz, 0, word);
  memcpy(buf + pixpos, pix, pixlen);
  return pixpos + pixlen;
}

/* Georeferencing of the GeoTIFF fixture: UTM 32N, 0.5 m pixels. */
static const double kScale[3] = {0.5, 0.5, 0.0};
static const double kTie[6] = {0, 0, 0, 350000.0, 5800000.0, 0};
static const uint16_t kKeys[24] = {1,    1,     0,  5,      /* version, 5 keys */
                                   1024, 0,     1,  1,      /* GTModelType: projected */
                                   1025, 0,     1,  1,      /* GTRasterType: area */
                                   1026, 34737, 22, 0,      /* GTCitation -> ascii */
                                   2057, 34736, 1,  0,      /* SemiMajorAxis -> double */
                                   3072, 0,     1,  32632}; /* ProjectedCSType */
static const double kGeoDouble[1] = {6378137.0};
static const char kGeoAscii[] = "WGS 84 / UTM zone 32N|";

/* A w x h 8-bit grey TIFF of `pix` (w*h bytes); with geo, a GeoTIFF with
 * the georeferencing above and GDAL nodata "0". Returns its size. */
static size_t tt_grey(uint8_t *buf, int big, uint32_t w, uint32_t h, int geo, const uint8_t *pix,
                      size_t pixlen) {
  uint8_t lw[4], lh[4], lbytes[4], s8[2], s1[2];
  le(lw, w, 4);
  le(lh, h, 4);
  le(lbytes, (uint64_t)w * h, 4);
  le(s8, 8, 2);
  le(s1, 1, 2);
  uint8_t scale[24], tie[48], keys[48], dbl[8];
  for (int i = 0; i < 3; i++) memcpy(scale + 8 * i, &kScale[i], 8);
  for (int i = 0; i < 6; i++) memcpy(tie + 8 * i, &kTie[i], 8);
  for (int i = 0; i < 24; i++) le(keys + 2 * i, kKeys[i], 2);
  memcpy(dbl, kGeoDouble, 8);
  tt_entry e[] = {
      {256, T_LONG, 1, lw},      {257, T_LONG, 1, lh},
      {258, T_SHORT, 1, s8},     {259, T_SHORT, 1, s1},
      {262, T_SHORT, 1, s1},     {273, T_LONG, 1, NULL},
      {277, T_SHORT, 1, s1},     {278, T_LONG, 1, lh},
      {279, T_LONG, 1, lbytes},  {33550, T_DOUBLE, 3, scale},
      {33922, T_DOUBLE, 6, tie}, {34735, T_SHORT, 24, keys},
      {34736, T_DOUBLE, 1, dbl}, {34737, T_ASCII, sizeof(kGeoAscii), kGeoAscii},
      {42113, T_ASCII, 2, "0"},
  };
  return tt_build(buf, big, e, geo ? 15 : 9, pix, pixlen);
}

/* In a little-endian classic TIFF (what OpenImageIO writes here), the
 * values of `tag` in the first directory, or NULL. */
static const uint8_t *tt_find(const uint8_t *f, size_t n, uint16_t tag, uint16_t *type,
                              uint32_t *count) {
  assert_true(n > 8 && f[0] == 'I' && f[1] == 'I' && f[2] == 42);
  uint32_t ifd = f[4] | f[5] << 8 | f[6] << 16 | (uint32_t)f[7] << 24;
  assert_true(ifd + 2 <= n);
  int ne = f[ifd] | f[ifd + 1] << 8;
  for (int i = 0; i < ne; i++) {
    const uint8_t *e = f + ifd + 2 + 12 * i;
    if ((e[0] | e[1] << 8) != tag) continue;
    *type = (uint16_t)(e[2] | e[3] << 8);
    *count = e[4] | e[5] << 8 | e[6] << 16 | (uint32_t)e[7] << 24;
    size_t bytes = (size_t)*count * tt_size(*type);
    if (bytes <= 4) return e + 8;
    uint32_t off = e[8] | e[9] << 8 | e[10] << 16 | (uint32_t)e[11] << 24;
    assert_true(off + bytes <= n);
    return f + off;
  }
  return NULL;
}

/* --- pixel types and allocation ------------------------------------------ */

static void pixtype_sizes_and_names(void **state) {
  (void)state;
  assert_int_equal(ts_pixtype_size(TS_PIX_U8), 1);
  assert_int_equal(ts_pixtype_size(TS_PIX_U16), 2);
  assert_int_equal(ts_pixtype_size(TS_PIX_F16), 2);
  assert_int_equal(ts_pixtype_size(TS_PIX_F32), 4);
  assert_int_equal(ts_pixtype_size((ts_pixtype)9), 0);
  assert_string_equal(ts_pixtype_name(TS_PIX_U8), "uint8");
  assert_string_equal(ts_pixtype_name(TS_PIX_F16), "half");
  assert_string_equal(ts_pixtype_name((ts_pixtype)9), "unknown");
}

static void alloc_checks_arguments(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  ts_image img;
  assert_int_equal(ts_image_alloc(&img, 0, 5, 1, TS_PIX_U8, err), TS_EINVAL);
  assert_null(img.pixels);
  assert_int_equal(ts_image_alloc(&img, 5, 5, 17, TS_PIX_U8, err), TS_EINVAL);
  assert_int_equal(ts_image_alloc(&img, 5, 5, 1, (ts_pixtype)7, err), TS_EINVAL);
  if (sizeof(size_t) == 8) {
    /* 2^31 * 2^31 * 16 * 4 bytes overflows 64 bits: refused, not wrapped */
    assert_int_equal(ts_image_alloc(&img, INT_MAX, INT_MAX, 16, TS_PIX_F32, err), TS_ENOMEM);
    assert_null(img.pixels);
  }
  assert_int_equal(ts_image_alloc(&img, 3, 2, 4, TS_PIX_F16, err), 0);
  assert_int_equal(img.width, 3);
  assert_int_equal(img.channels, 4);
  assert_null(img.meta);
  for (size_t i = 0; i < 24; i++) assert_int_equal(((uint16_t *)img.pixels)[i], 0);
  ts_image_free(&img);
  assert_null(img.pixels);
  ts_image_free(&img); /* twice is harmless */
}

/* --- round trips --------------------------------------------------------- */

/* A fresh w x h x c image of type t survives a write to `name` and a read. */
static void roundtrip_new(void **state, const char *name, int w, int h, int c, ts_pixtype t) {
  ts_image img;
  make_image(&img, w, h, c, t);
  roundtrip_exact(state, name, &img);
  ts_image_free(&img);
}

static void png8_grey_roundtrip(void **state) {
  roundtrip_new(state, "grey.png", 37, 21, 1, TS_PIX_U8);
}

static void png8_rgb_roundtrip(void **state) {
  roundtrip_new(state, "rgb.png", 40, 30, 3, TS_PIX_U8);
}

/* Random alpha, including 0: any premultiplication would show. */
static void png8_rgba_roundtrip(void **state) {
  roundtrip_new(state, "rgba.png", 33, 17, 4, TS_PIX_U8);
}

static void png16_roundtrip(void **state) {
  roundtrip_new(state, "rgb16.png", 29, 31, 3, TS_PIX_U16);
  roundtrip_new(state, "ya16.png", 29, 31, 2, TS_PIX_U16);
}

static void tiff16_scanline_roundtrip(void **state) {
  roundtrip_new(state, "rgba16.tif", 45, 23, 4, TS_PIX_U16);
  roundtrip_new(state, "six.tiff", 45, 23, 6, TS_PIX_U16); /* multi-channel */
}

/* Our writer makes scanline TIFFs; oiiotool retiles one. */
static void tiff16_tiled_read(void **state) {
  if (system("command -v oiiotool >/dev/null 2>&1") != 0)
    fail_msg("oiiotool is not installed: it is Debian's openimageio-tools, which deploy/install-deps.sh installs");
  char src[PATH_MAX], dst[PATH_MAX], cmd[3 * PATH_MAX], err[TS_ERR_LEN];
  ts_image img, back;
  path_of(state, "scan.tif", src);
  path_of(state, "tiled.tif", dst);
  make_image(&img, 70, 50, 3, TS_PIX_U16);
  assert_int_equal(ts_image_write(src, &img, NULL, err), 0);
  snprintf(cmd, sizeof(cmd), "oiiotool '%s' --tile 32 32 -o '%s'", src, dst);
  assert_int_equal(system(cmd), 0);
  size_t n;
  uint8_t *f = read_file(dst, &n);
  uint16_t type;
  uint32_t count;
  assert_non_null(tt_find(f, n, 322, &type, &count)); /* TileWidth */
  free(f);
  assert_int_equal(ts_image_read(dst, &back, NULL, err), 0);
  assert_same_image(&img, &back);
  ts_image_free(&img);
  ts_image_free(&back);
}

static void jpeg_roundtrip_approx(void **state) {
  char path[PATH_MAX], err[TS_ERR_LEN];
  ts_image img, back;
  path_of(state, "g.jpg", path);
  make_gradient(&img, 96, 64, 3);
  assert_int_equal(ts_image_write(path, &img, NULL, err), 0);
  assert_int_equal(ts_image_read(path, &back, NULL, err), 0);
  assert_int_equal(back.width, 96);
  assert_int_equal(back.height, 64);
  assert_int_equal(back.channels, 3);
  assert_int_equal(back.type, TS_PIX_U8);
  long sum = 0;
  int worst = 0;
  for (size_t i = 0; i < image_bytes(&img); i++) {
    int d = abs(((uint8_t *)img.pixels)[i] - ((uint8_t *)back.pixels)[i]);
    sum += d;
    worst = d > worst ? d : worst;
  }
  assert_true(worst <= 12);
  assert_true(sum <= (long)image_bytes(&img)); /* mean error under 1 */
  ts_image_free(&img);
  ts_image_free(&back);
}

/* JPEG holds grey or RGB: alpha and extra channels are dropped. */
static void jpeg_drops_alpha(void **state) {
  char path[PATH_MAX], err[TS_ERR_LEN];
  ts_image img, back;
  path_of(state, "a.jpg", path);
  make_gradient(&img, 32, 32, 4);
  assert_int_equal(ts_image_write(path, &img, NULL, err), 0);
  assert_int_equal(ts_image_read(path, &back, NULL, err), 0);
  assert_int_equal(back.channels, 3);
  ts_image_free(&back);
  ts_image_free(&img);
  make_gradient(&img, 32, 32, 2);
  assert_int_equal(ts_image_write(path, &img, NULL, err), 0);
  assert_int_equal(ts_image_read(path, &back, NULL, err), 0);
  assert_int_equal(back.channels, 1);
  ts_image_free(&back);
  ts_image_free(&img);
}

static void exr_half_roundtrip(void **state) {
  ts_image img;
  make_image(&img, 31, 19, 4, TS_PIX_F16);
  static const uint16_t special[] = {0x0000, 0x8000, 0x0001, 0x03ff, 0x0400,
                                     0x3c00, 0x7bff, 0xfbff, 0x7c00, 0xfc00};
  memcpy(img.pixels, special, sizeof(special));
  roundtrip_exact(state, "half.exr", &img);
  ts_image_free(&img);
}

static void exr_float_roundtrip(void **state) {
  ts_image img;
  make_image(&img, 23, 27, 3, TS_PIX_F32);
  float *p = img.pixels;
  p[0] = 1e-40f; /* subnormal */
  p[1] = -3.4e38f;
  p[2] = 1.0f / 3.0f;
  roundtrip_exact(state, "float.exr", &img);
  ts_image_free(&img);
  roundtrip_new(state, "floatgrey.exr", 23, 27, 1, TS_PIX_F32);
}

/* Types a format cannot hold: float to 8-bit PNG (clamped, rounded to
 * nearest), 8-bit to half and 16-bit to float EXR, half to float TIFF. */
static void write_converts_types(void **state) {
  char path[PATH_MAX], err[TS_ERR_LEN];
  ts_image img, back;
  path_of(state, "f.png", path);
  assert_int_equal(ts_image_alloc(&img, 6, 1, 1, TS_PIX_F32, err), 0);
  const float in[6] = {0.0f, 0.5f, 1.0f, 2.0f, -1.0f, 0.25f};
  const uint8_t want[6] = {0, 128, 255, 255, 0, 64};
  memcpy(img.pixels, in, sizeof(in));
  assert_int_equal(ts_image_write(path, &img, NULL, err), 0);
  assert_int_equal(ts_image_read(path, &back, NULL, err), 0);
  assert_int_equal(back.type, TS_PIX_U8);
  assert_memory_equal(back.pixels, want, 6);
  ts_image_free(&back);
  ts_image_free(&img);

  make_image(&img, 16, 8, 3, TS_PIX_U8);
  path_of(state, "u8.exr", path);
  assert_int_equal(ts_image_write(path, &img, NULL, err), 0);
  assert_int_equal(ts_image_read(path, &back, NULL, err), 0);
  assert_int_equal(back.type, TS_PIX_F16);
  uint8_t a[16 * 8], b[16 * 8];
  for (int c = 0; c < 3; c++) { /* half holds every 8-bit level exactly enough */
    ts_image_channel8(&img, c, a);
    ts_image_channel8(&back, c, b);
    assert_memory_equal(a, b, sizeof(a));
  }
  ts_image_free(&back);
  ts_image_free(&img);

  make_image(&img, 16, 8, 1, TS_PIX_U16);
  path_of(state, "u16.exr", path);
  assert_int_equal(ts_image_write(path, &img, NULL, err), 0);
  assert_int_equal(ts_image_read(path, &back, NULL, err), 0);
  assert_int_equal(back.type, TS_PIX_F32);
  for (int i = 0; i < 16 * 8; i++)
    assert_int_equal(lrintf(((float *)back.pixels)[i] * 65535.0f), ((uint16_t *)img.pixels)[i]);
  ts_image_free(&back);
  ts_image_free(&img);

  make_image(&img, 16, 8, 2, TS_PIX_F16);
  path_of(state, "h.tif", path);
  assert_int_equal(ts_image_write(path, &img, NULL, err), 0);
  assert_int_equal(ts_image_read(path, &back, NULL, err), 0);
  assert_int_equal(back.type, TS_PIX_F32);
  for (int i = 0; i < 16 * 8 * 2; i++)
    assert_true(((float *)back.pixels)[i] == ts_image_sample(&img, (i / 2) % 16, i / 32, i % 2));
  ts_image_free(&back);
  ts_image_free(&img);
}

/* --- metadata ------------------------------------------------------------ */

static void geotiff_tags_pass_through(void **state) {
  char src[PATH_MAX], dst[PATH_MAX], err[TS_ERR_LEN], v[512], v2[512];
  uint8_t pix[24 * 16], buf[4096];
  for (int i = 0; i < 24 * 16; i++) pix[i] = (uint8_t)(i * 7);
  path_of(state, "geo.tif", src);
  path_of(state, "out.tif", dst);
  write_file(src, buf, tt_grey(buf, 0, 24, 16, 1, pix, sizeof(pix)));

  ts_image img, back;
  assert_int_equal(ts_image_read(src, &img, NULL, err), 0);
  assert_int_equal(img.width, 24);
  assert_memory_equal(img.pixels, pix, sizeof(pix));
  assert_int_equal(ts_meta_get(img.meta, "GeoTIFF:ModelPixelScale", v, sizeof(v)), 0);
  assert_string_equal(v, "0.5, 0.5, 0");
  assert_int_equal(ts_meta_get(img.meta, "GeoTIFF:GeoAsciiParams", v, sizeof(v)), 0);
  assert_string_equal(v, kGeoAscii);
  assert_int_equal(ts_meta_get(img.meta, "gdal:nodata", v, sizeof(v)), 0); /* any case */
  assert_string_equal(v, "0");
  assert_int_equal(ts_meta_get(img.meta, "GeoTIFF:GeoKeyDirectory", v, sizeof(v)), 0);
  assert_true(strncmp(v, "1, 1, 0, 5, 1024, 0, 1, 1,", 26) == 0);

  /* Through our writer: the tags are in the new file, byte for byte. */
  assert_int_equal(ts_image_write(dst, &img, img.meta, err), 0);
  size_t n;
  uint8_t *f = read_file(dst, &n);
  uint16_t type;
  uint32_t count;
  const uint8_t *p = tt_find(f, n, 33550, &type, &count);
  assert_non_null(p);
  assert_int_equal(type, T_DOUBLE);
  assert_int_equal(count, 3);
  assert_memory_equal(p, kScale, sizeof(kScale));
  p = tt_find(f, n, 33922, &type, &count);
  assert_non_null(p);
  assert_memory_equal(p, kTie, sizeof(kTie));
  p = tt_find(f, n, 34735, &type, &count);
  assert_non_null(p);
  assert_int_equal(type, T_SHORT);
  assert_int_equal(count, 24);
  for (int i = 0; i < 24; i++) assert_int_equal(p[2 * i] | p[2 * i + 1] << 8, kKeys[i]);
  p = tt_find(f, n, 34736, &type, &count);
  assert_non_null(p);
  assert_memory_equal(p, kGeoDouble, 8);
  p = tt_find(f, n, 34737, &type, &count);
  assert_non_null(p);
  assert_int_equal(count, sizeof(kGeoAscii));
  assert_memory_equal(p, kGeoAscii, sizeof(kGeoAscii));
  p = tt_find(f, n, 42113, &type, &count);
  assert_non_null(p);
  assert_int_equal(type, T_ASCII);
  assert_memory_equal(p, "0", 2);
  assert_non_null(tt_find(f, n, 259, &type, &count)); /* OpenImageIO's own tags kept */
  free(f);

  /* ... and the file still reads, pixels and tags. */
  assert_int_equal(ts_image_read(dst, &back, NULL, err), 0);
  assert_same_image(&img, &back);
  assert_int_equal(ts_meta_get(back.meta, "GeoTIFF:ModelTiePoint", v, sizeof(v)), 0);
  assert_int_equal(ts_meta_get(img.meta, "GeoTIFF:ModelTiePoint", v2, sizeof(v2)), 0);
  assert_string_equal(v, v2);
  ts_image_free(&back);

  /* Only TIFF outputs carry them. */
  path_of(state, "out.png", dst);
  assert_int_equal(ts_image_write(dst, &img, img.meta, err), 0);
  assert_int_equal(ts_image_read(dst, &back, NULL, err), 0);
  assert_int_equal(ts_meta_get(back.meta, "GeoTIFF:ModelPixelScale", v, sizeof(v)), TS_ENOENT);
  ts_image_free(&back);
  ts_image_free(&img);
}

static void geotiff_read_bigtiff(void **state) {
  char path[PATH_MAX], err[TS_ERR_LEN], v[256];
  uint8_t pix[8 * 4] = {1, 2, 3}, buf[4096];
  path_of(state, "big.tif", path);
  write_file(path, buf, tt_grey(buf, 1, 8, 4, 1, pix, sizeof(pix)));
  ts_image img;
  assert_int_equal(ts_image_read(path, &img, NULL, err), 0);
  assert_memory_equal(img.pixels, pix, sizeof(pix));
  assert_int_equal(ts_meta_get(img.meta, "GeoTIFF:ModelPixelScale", v, sizeof(v)), 0);
  assert_string_equal(v, "0.5, 0.5, 0");
  ts_image_free(&img);
}

/* Plain attributes pass through; encoding details of the source do not. */
static void meta_passes_and_filters(void **state) {
  char src[PATH_MAX], dst[PATH_MAX], err[TS_ERR_LEN], v[256];
  ts_image img, mid, back;
  path_of(state, "src.jpg", src);
  path_of(state, "dst.tif", dst);
  make_gradient(&img, 32, 16, 3);
  assert_int_equal(ts_meta_set(&img.meta, "ImageDescription", "brick, synthesized"), 0);
  assert_int_equal(ts_meta_set(&img.meta, "Artist", "texsyn"), 0);
  assert_int_equal(ts_meta_set(&img.meta, "Artist", "texsyn test"), 0); /* replaces */
  assert_int_equal(ts_image_write(src, &img, img.meta, err), 0);
  assert_int_equal(ts_image_read(src, &mid, NULL, err), 0);
  assert_int_equal(ts_meta_get(mid.meta, "ImageDescription", v, sizeof(v)), 0);
  assert_string_equal(v, "brick, synthesized");
  assert_int_equal(ts_meta_get(mid.meta, "jpeg:subsampling", v, sizeof(v)), 0);

  assert_int_equal(ts_image_write(dst, &mid, mid.meta, err), 0);
  assert_int_equal(ts_image_read(dst, &back, NULL, err), 0);
  assert_int_equal(ts_meta_get(back.meta, "Artist", v, sizeof(v)), 0);
  assert_string_equal(v, "texsyn test");
  assert_int_equal(ts_meta_get(back.meta, "compression", v, sizeof(v)), 0);
  assert_string_equal(v, "zip"); /* lossless, not the source's "jpeg" */
  assert_int_equal(ts_meta_get(back.meta, "jpeg:subsampling", v, sizeof(v)), TS_ENOENT);
  /* small buffers truncate */
  assert_int_equal(ts_meta_get(back.meta, "Artist", v, 4), 0);
  assert_string_equal(v, "tex");
  assert_int_equal(ts_meta_get(back.meta, "NoSuchThing", v, sizeof(v)), TS_ENOENT);
  assert_int_equal(ts_meta_get(NULL, "Artist", v, sizeof(v)), TS_ENOENT);
  assert_int_equal(ts_meta_set(NULL, "Artist", "x"), TS_EINVAL);
  ts_image_free(&back);
  ts_image_free(&mid);
  ts_image_free(&img);
}

/* --- bad input ------------------------------------------------------------ */

static void read_missing_file(void **state) {
  char path[PATH_MAX];
  path_of(state, "nope.png", path);
  expect_read_error(path, TS_ENOENT);
  path_of(state, "nodir/nope.png", path);
  expect_read_error(path, TS_ENOENT);
}

static void read_garbage_file(void **state) {
  char path[PATH_MAX];
  uint8_t junk[1000];
  uint32_t r = 99;
  for (size_t i = 0; i < sizeof(junk); i++) {
    r = r * 1103515245u + 12345u;
    junk[i] = (uint8_t)(r >> 16);
  }
  path_of(state, "junk.png", path);
  write_file(path, junk, sizeof(junk));
  expect_read_error(path, TS_EFORMAT);
  path_of(state, "empty.tif", path);
  write_file(path, junk, 0);
  expect_read_error(path, TS_EFORMAT);
  path_of(state, "", path); /* the scratch directory itself */
  expect_read_error(path, TS_EFORMAT);
}

/* Writes img as name, then cuts it to `fraction` percent as "cut-" name. */
static void write_and_cut(void **state, const char *name, const ts_image *img, int percent,
                          char *cut) {
  char path[PATH_MAX], err[TS_ERR_LEN], cutname[64];
  path_of(state, name, path);
  assert_int_equal(ts_image_write(path, img, NULL, err), 0);
  struct stat st;
  assert_int_equal(stat(path, &st), 0);
  snprintf(cutname, sizeof(cutname), "cut-%s", name);
  path_of(state, cutname, cut);
  cut_file(path, cut, (size_t)st.st_size * percent / 100);
}

static void read_truncated_png(void **state) {
  char cut[PATH_MAX];
  ts_image img;
  make_image(&img, 64, 64, 3, TS_PIX_U8);
  write_and_cut(state, "t.png", &img, 60, cut);
  expect_read_error(cut, TS_EFORMAT);
  ts_image_free(&img);
}

static void read_truncated_jpeg(void **state) {
  char cut[PATH_MAX];
  ts_image img;
  make_image(&img, 64, 64, 3, TS_PIX_U8);
  write_and_cut(state, "t.jpg", &img, 50, cut);
  expect_read_error(cut, TS_EFORMAT);
  ts_image_free(&img);
}

static void read_truncated_exr(void **state) {
  char cut[PATH_MAX];
  ts_image img;
  make_image(&img, 64, 64, 3, TS_PIX_F16);
  write_and_cut(state, "t.exr", &img, 70, cut);
  expect_read_error(cut, TS_EFORMAT);
  ts_image_free(&img);
}

/* Both kinds: OpenImageIO puts the directory last, so a cut loses it; a
 * TIFF with the directory first loses only pixel data (libtiff reports it
 * on a read that still "succeeds"). */
static void read_truncated_tiff(void **state) {
  char cut[PATH_MAX], path[PATH_MAX], err[TS_ERR_LEN];
  ts_image img;
  make_image(&img, 64, 64, 1, TS_PIX_U16);
  write_and_cut(state, "t.tif", &img, 80, cut);
  expect_read_error(cut, TS_EFORMAT);
  ts_image_free(&img);

  uint8_t pix[64 * 64], buf[8192];
  memset(pix, 200, sizeof(pix));
  size_t n = tt_grey(buf, 0, 64, 64, 0, pix, sizeof(pix));
  path_of(state, "first.tif", path);
  write_file(path, buf, n);
  assert_int_equal(ts_image_read(path, &img, NULL, err), 0); /* whole: fine */
  ts_image_free(&img);
  path_of(state, "first-cut.tif", path);
  write_file(path, buf, n - 1000);
  expect_read_error(path, TS_EFORMAT);
}

static uint32_t crc32_png(const uint8_t *p, size_t n) {
  uint32_t c = 0xffffffffu;
  for (size_t i = 0; i < n; i++) {
    c ^= p[i];
    for (int k = 0; k < 8; k++) c = (c >> 1) ^ (0xedb88320u & (0u - (c & 1)));
  }
  return ~c;
}

static void be32(uint8_t *p, uint32_t v) {
  p[0] = (uint8_t)(v >> 24);
  p[1] = (uint8_t)(v >> 16);
  p[2] = (uint8_t)(v >> 8);
  p[3] = (uint8_t)v;
}

/* A 100000 x 100000 header is refused from the header, the same way from
 * a file, from memory and by the probe: the message names the file, the
 * size, the limit and the option that raises it. Under a 1 GiB address
 * space limit: refused before any pixel memory (10 GB) is asked for. */
static void expect_huge(const char *path, const uint8_t *bytes, size_t n) {
  struct rlimit old, lim;
  assert_int_equal(getrlimit(RLIMIT_AS, &old), 0);
  lim = old;
  unsigned long vsz_pages = 0;
  FILE *statm = fopen("/proc/self/statm", "r");
  if (statm != NULL) {
    if (fscanf(statm, "%lu", &vsz_pages) != 1) vsz_pages = 0;
    fclose(statm);
  }
  if (!TS_ASAN && vsz_pages > 0) { /* ASan reserves terabytes of address space */
    lim.rlim_cur = (rlim_t)vsz_pages * (rlim_t)sysconf(_SC_PAGESIZE) + (1ull << 30);
    assert_int_equal(setrlimit(RLIMIT_AS, &lim), 0);
  }
  char err[TS_ERR_LEN];
  ts_image img;
  ts_image_info info;
  expect_read_error(path, TS_ETOOBIG);
  assert_int_equal(ts_image_read(path, &img, NULL, err), TS_ETOOBIG);
  assert_non_null(strstr(err, "100000x100000 image (10000000000 pixels)"));
  assert_non_null(strstr(err, "limit of 268435456 pixels"));
  assert_non_null(strstr(err, "raise it with --max-pixels"));
  ts_image_limits server = {1000000, "texsyn-server --max-pixels"};
  assert_int_equal(ts_image_read_mem("client.img", bytes, n, &img, &server, err), TS_ETOOBIG);
  assert_null(img.pixels);
  assert_non_null(strstr(err, "client.img: 100000x100000 image"));
  assert_non_null(strstr(err, "limit of 1000000 pixels; raise it with texsyn-server --max-pixels"));
  assert_int_equal(ts_image_probe_mem("client.img", bytes, n, &server, &info, err), TS_ETOOBIG);
  assert_non_null(strstr(err, "client.img: 100000x100000 image"));
  assert_int_equal(setrlimit(RLIMIT_AS, &old), 0);
}

/* A valid PNG header (IHDR with a correct CRC) claiming 100000 x 100000
 * grey pixels, followed by a tiny IDAT: refused from the header alone. */
static void read_huge_header_refused(void **state) {
  char path[PATH_MAX];
  uint8_t png[8 + 25 + 12 + 12] = {137, 'P', 'N', 'G', 13, 10, 26, 10};
  uint8_t *ihdr = png + 8;
  be32(ihdr, 13);
  memcpy(ihdr + 4, "IHDR", 4);
  be32(ihdr + 8, 100000);
  be32(ihdr + 12, 100000);
  ihdr[16] = 8; /* depth; colour type, compression, filter, interlace 0 */
  be32(ihdr + 21, crc32_png(ihdr + 4, 17));
  uint8_t *idat = ihdr + 25;
  be32(idat, 0);
  memcpy(idat + 4, "IDAT", 4);
  be32(idat + 8, crc32_png(idat + 4, 4));
  uint8_t *iend = idat + 12;
  be32(iend, 0);
  memcpy(iend + 4, "IEND", 4);
  be32(iend + 8, crc32_png(iend + 4, 4));
  path_of(state, "huge.png", path);
  write_file(path, png, sizeof(png));
  expect_huge(path, png, sizeof(png));

  uint8_t buf[1024], pix[16] = {0};
  path_of(state, "huge.tif", path);
  size_t n = tt_grey(buf, 0, 100000, 100000, 0, pix, sizeof(pix));
  write_file(path, buf, n);
  expect_huge(path, buf, n);
  path_of(state, "huge-big.tif", path); /* BigTIFF */
  n = tt_grey(buf, 1, 100000, 100000, 0, pix, sizeof(pix));
  write_file(path, buf, n);
  expect_huge(path, buf, n);
}

static void read_honours_max_pixels(void **state) {
  char path[PATH_MAX], err[TS_ERR_LEN];
  ts_image img, back;
  path_of(state, "64.png", path);
  make_image(&img, 64, 64, 1, TS_PIX_U8);
  assert_int_equal(ts_image_write(path, &img, NULL, err), 0);
  ts_image_limits lim = {64 * 64 - 1};
  assert_int_equal(ts_image_read(path, &back, &lim, err), TS_ETOOBIG);
  assert_non_null(strstr(err, path));
  assert_non_null(strstr(err, "64x64"));
  assert_non_null(strstr(err, "4095"));
  assert_non_null(strstr(err, "--max-pixels"));
  lim.max_pixels = 64 * 64;
  assert_int_equal(ts_image_read(path, &back, &lim, err), 0);
  ts_image_free(&back);
  lim.max_pixels = 0; /* 0 means the default */
  assert_int_equal(ts_image_read(path, &back, &lim, err), 0);
  ts_image_free(&back);
  ts_image_free(&img);
}

/* Reads a file's bytes as ts_image_read_mem: the same image as from the
 * file, metadata included. */
static void expect_mem_same(const char *path) {
  char err[TS_ERR_LEN], v[256], w[256];
  size_t n;
  uint8_t *bytes = read_file(path, &n);
  ts_image a, b;
  ts_image_info info;
  assert_int_equal(ts_image_read(path, &a, NULL, err), 0);
  assert_int_equal(ts_image_read_mem("mem", bytes, n, &b, NULL, err), 0);
  assert_same_image(&a, &b);
  assert_int_equal(ts_image_probe_mem("mem", bytes, n, NULL, &info, err), 0);
  assert_int_equal(info.width, a.width);
  assert_int_equal(info.height, a.height);
  assert_int_equal(info.channels, a.channels);
  assert_int_equal(info.type, a.type);
  int geo = ts_meta_get(a.meta, "GeoTIFF:ModelTiePoint", v, sizeof(v));
  assert_int_equal(ts_meta_get(b.meta, "GeoTIFF:ModelTiePoint", w, sizeof(w)), geo);
  if (geo == 0) assert_string_equal(v, w);
  ts_image_free(&a);
  ts_image_free(&b);
  free(bytes);
}

static void read_mem_matches_file(void **state) {
  static const struct {
    const char *name;
    int c;
    ts_pixtype t;
  } files[] = {{"m.png", 3, TS_PIX_U8}, {"m16.png", 2, TS_PIX_U16}, {"m.jpg", 3, TS_PIX_U8},
               {"m.tif", 4, TS_PIX_U16}, {"m.exr", 3, TS_PIX_F16}};
  char path[PATH_MAX], err[TS_ERR_LEN];
  for (size_t i = 0; i < sizeof(files) / sizeof(files[0]); i++) {
    ts_image img;
    make_image(&img, 24, 16, files[i].c, files[i].t);
    path_of(state, files[i].name, path);
    assert_int_equal(ts_image_write(path, &img, NULL, err), 0);
    expect_mem_same(path);
    ts_image_free(&img);
  }
  uint8_t pix[8 * 4] = {1, 2, 3}, buf[4096];
  path_of(state, "geo.tif", path);
  write_file(path, buf, tt_grey(buf, 0, 8, 4, 1, pix, sizeof(pix)));
  expect_mem_same(path);
}

/* What the coordinator refuses at submit: each gets one line naming the
 * file and saying what is wrong, from a file and from memory alike. */
static void read_refuses_non_images(void **state) {
  static const struct {
    const char *name, *bytes, *want;
    size_t n;
  } cases[] = {
      {"empty.png", "", "empty.png: empty file (0 bytes), not an image", 0},
      {"text.png", "hello, world\n", "text.png: not a PNG, JPEG, TIFF or OpenEXR image (starts "
                                    "with bytes 68 65 6c 6c 6f 2c 20 77)", 13},
      {"tiny.png", "\x89P", "tiny.png: not a PNG, JPEG, TIFF or OpenEXR image (starts with "
                            "bytes 89 50)", 2},
      {"bmp.png", "BM\x3a\0\0\0", "not a PNG, JPEG, TIFF or OpenEXR", 6},
      {"head.png", "\x89PNG\r\n\x1a\n", "head.png: unreadable or truncated image: no IEND chunk", 8},
      /* Found by fuzz_image: libpng took 1.9 GB for a text chunk this
       * claimed; chunk lengths are now checked against the file first. */
      {"bigtext.png",
       "\x89PNG\r\n\x1a\n\0\0\0\x0dIHDR\0\0\0\x08\0\0\0\x08\x08\x02\0\0\0\x4b\x6d\x29\xdc"
       "\x6d\x66\x6f\x63tEXtabcdefghijkl",
       "bigtext.png: unreadable or truncated image: chunk 'tEXt' claims 1835429731 bytes, the file "
       "has 8 left",
       53},
      /* Found by fuzz_image: OpenEXR would allocate what the attribute
       * claims (here 2 GB) before reading it. */
      {"attr.exr", "\x76\x2f\x31\x01\x02\0\0\0foo\0string\0\xff\xff\xff\x7f",
       "attr.exr: not a readable openexr image: header attribute 'foo' claims 2147483647 bytes, "
       "more than the file holds",
       23},
  };
  char path[PATH_MAX], err[TS_ERR_LEN];
  for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
    ts_image img;
    path_of(state, cases[i].name, path);
    write_file(path, cases[i].bytes, cases[i].n);
    expect_read_error(path, TS_EFORMAT);
    assert_int_equal(ts_image_read_mem(cases[i].name, cases[i].bytes, cases[i].n, &img, NULL, err),
                     TS_EFORMAT);
    print_message("     err: %s\n", err);
    assert_non_null(strstr(err, cases[i].want));
    assert_int_equal(ts_image_probe_mem(cases[i].name, cases[i].bytes, cases[i].n, NULL, NULL, err),
                     TS_EFORMAT);
    assert_non_null(strstr(err, cases[i].want));
  }
}

/* The probe reads the header only: a JPEG cut inside its pixels passes
 * it, and the read then fails (a cut PNG fails the chunk walk already); a header with tiles over the limit fails
 * both. */
static void probe_reads_the_header_only(void **state) {
  char path[PATH_MAX], cut[PATH_MAX], err[TS_ERR_LEN];
  ts_image img;
  make_image(&img, 64, 64, 3, TS_PIX_U8);
  write_and_cut(state, "p.jpg", &img, 50, cut);
  ts_image_free(&img);
  size_t n;
  uint8_t *bytes = read_file(cut, &n);
  ts_image_info info;
  assert_int_equal(ts_image_probe_mem("cut.jpg", bytes, n, NULL, &info, err), 0);
  assert_int_equal(info.width, 64);
  assert_int_equal(info.channels, 3);
  assert_int_equal(info.type, TS_PIX_U8);
  assert_int_equal(ts_image_read_mem("cut.jpg", bytes, n, &img, NULL, err), TS_EFORMAT);
  assert_non_null(strstr(err, "cut.jpg: unreadable or truncated image"));
  free(bytes);

  /* 16 x 16 pixels in one 65536 x 65536 tile (4 Gpixels). */
  uint8_t lw[4], lt[4], s8[2], s1[2], off[4], cnt[4], buf[1024];
  le(lw, 16, 4);
  le(lt, 65536, 4);
  le(s8, 8, 2);
  le(s1, 1, 2);
  le(off, 8, 4);
  le(cnt, 16, 4);
  tt_entry e[] = {{256, T_LONG, 1, lw},  {257, T_LONG, 1, lw},  {258, T_SHORT, 1, s8},
                  {259, T_SHORT, 1, s1}, {262, T_SHORT, 1, s1}, {277, T_SHORT, 1, s1},
                  {322, T_LONG, 1, lt},  {323, T_LONG, 1, lt},  {324, T_LONG, 1, off},
                  {325, T_LONG, 1, cnt}};
  path_of(state, "tile.tif", path);
  write_file(path, buf, tt_build(buf, 0, e, 10, buf, 0));
  expect_read_error(path, TS_ETOOBIG);
  assert_int_equal(ts_image_read(path, &img, NULL, err), TS_ETOOBIG);
  assert_non_null(strstr(err, "65536x65536 tiles are over the limit of 268435456 pixels"));
}

static void write_unknown_extension(void **state) {
  char path[PATH_MAX], err[TS_ERR_LEN];
  ts_image img;
  make_image(&img, 4, 4, 1, TS_PIX_U8);
  path_of(state, "out.xyz", path);
  assert_int_equal(ts_image_write(path, &img, NULL, err), TS_EINVAL);
  assert_non_null(strstr(err, path));
  path_of(state, "noextension", path);
  assert_int_equal(ts_image_write(path, &img, NULL, err), TS_EINVAL);
  assert_int_equal(scratch_count(state), 0);
  ts_image bad = img;
  bad.channels = 0;
  path_of(state, "bad.png", path);
  assert_int_equal(ts_image_write(path, &bad, NULL, err), TS_EINVAL);
  ts_image_free(&img);
}

/* The failed writer's global OpenImageIO error must not reach the next
 * call's message. */
static void errors_do_not_leak(void **state) {
  char path[PATH_MAX], err[TS_ERR_LEN];
  ts_image img, back;
  make_image(&img, 4, 4, 1, TS_PIX_U8);
  path_of(state, "leaky.xyz", path);
  assert_int_equal(ts_image_write(path, &img, NULL, err), TS_EINVAL);
  path_of(state, "junk.tif", path);
  write_file(path, "not an image at all", 19);
  assert_int_equal(ts_image_read(path, &back, NULL, err), TS_EFORMAT);
  assert_null(strstr(err, "leaky"));
  ts_image_free(&img);
}

static void write_into_missing_dir(void **state) {
  char path[PATH_MAX], err[TS_ERR_LEN];
  ts_image img;
  make_image(&img, 8, 8, 3, TS_PIX_U8);
  path_of(state, "nodir/out.png", path);
  assert_int_equal(ts_image_write(path, &img, NULL, err), TS_EIO);
  assert_non_null(strstr(err, path));
  print_message("     err: %s\n", err);
  assert_int_equal(scratch_count(state), 0);
  ts_image_free(&img);
}

/* A directory in the way makes the final rename fail after the whole file
 * was written: the temporary must still go. */
static void write_failure_leaves_no_temp(void **state) {
  char path[PATH_MAX], err[TS_ERR_LEN];
  ts_image img;
  make_image(&img, 8, 8, 3, TS_PIX_U16);
  path_of(state, "taken.tif", path);
  assert_int_equal(mkdir(path, 0700), 0);
  assert_int_equal(ts_image_write(path, &img, NULL, err), TS_EIO);
  assert_non_null(strstr(err, path));
  print_message("     err: %s\n", err);
  assert_int_equal(scratch_count(state), 1);
  ts_image_free(&img);
}

static void write_replaces_atomically(void **state) {
  char path[PATH_MAX], err[TS_ERR_LEN];
  ts_image a, b, back;
  path_of(state, "same.png", path);
  make_image(&a, 16, 16, 3, TS_PIX_U8);
  make_gradient(&b, 20, 10, 3);
  assert_int_equal(ts_image_write(path, &a, NULL, err), 0);
  assert_int_equal(ts_image_write(path, &b, NULL, err), 0);
  assert_int_equal(ts_image_read(path, &back, NULL, err), 0);
  assert_same_image(&b, &back);
  assert_int_equal(scratch_count(state), 1);
  ts_image_free(&a);
  ts_image_free(&b);
  ts_image_free(&back);
}

/* --- pixel helpers -------------------------------------------------------- */

static void sample_converts_exactly(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  ts_image h;
  assert_int_equal(ts_image_alloc(&h, 8, 1, 1, TS_PIX_F16, err), 0);
  const uint16_t bits[8] = {0x3c00, 0x0001, 0xfbff, 0x7c00, 0x8000, 0x3555, 0x0400, 0x03ff};
  memcpy(h.pixels, bits, sizeof(bits));
  assert_true(ts_image_sample(&h, 0, 0, 0) == 1.0f);
  assert_true(ts_image_sample(&h, 1, 0, 0) == 0x1p-24f);
  assert_true(ts_image_sample(&h, 2, 0, 0) == -65504.0f);
  assert_true(isinf(ts_image_sample(&h, 3, 0, 0)));
  assert_true(ts_image_sample(&h, 4, 0, 0) == 0.0f && signbit(ts_image_sample(&h, 4, 0, 0)));
  assert_true(ts_image_sample(&h, 5, 0, 0) == 0x1.554p-2f); /* 0.333251953125 */
  assert_true(ts_image_sample(&h, 6, 0, 0) == 0x1p-14f);
  assert_true(ts_image_sample(&h, 7, 0, 0) == 0x3ffp-24f);
  ts_image_free(&h);

  ts_image u;
  assert_int_equal(ts_image_alloc(&u, 2, 2, 2, TS_PIX_U16, err), 0);
  ((uint16_t *)u.pixels)[7] = 65535;
  ((uint16_t *)u.pixels)[6] = 32768;
  assert_true(ts_image_sample(&u, 1, 1, 1) == 1.0f);
  assert_true(ts_image_sample(&u, 1, 1, 0) == 32768.0f / 65535.0f);
  ts_image_free(&u);
}

static void luma8_known_values(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  uint8_t out[6];
  ts_image c8;
  assert_int_equal(ts_image_alloc(&c8, 6, 1, 3, TS_PIX_U8, err), 0);
  const uint8_t rgb[18] = {255, 0, 0, 0, 255, 0, 0, 0, 255, 255, 255, 255, 0, 0, 0, 10, 20, 30};
  memcpy(c8.pixels, rgb, sizeof(rgb));
  ts_image_luma8(&c8, out);
  /* 0.299*255 = 76.245, 0.587*255 = 149.685, 0.114*255 = 29.07,
   * 2.99 + 11.74 + 3.42 = 18.15 */
  const uint8_t want8[6] = {76, 150, 29, 255, 0, 18};
  assert_memory_equal(out, want8, 6);
  ts_image_channel8(&c8, 2, out);
  assert_int_equal(out[2], 255);
  assert_int_equal(out[5], 30);
  ts_image_free(&c8);

  ts_image w16;
  assert_int_equal(ts_image_alloc(&w16, 3, 1, 4, TS_PIX_U16, err), 0);
  uint16_t *p = w16.pixels;
  for (int i = 0; i < 4; i++) p[i] = 65535; /* white */
  p[4] = p[5] = p[6] = 257 * 100;           /* grey 100 */
  p[8] = 128;                               /* 128/257 < 0.5 -> 0 */
  p[9] = 129;                               /* 0.587*129/257 < 0.5 -> 0 */
  ts_image_luma8(&w16, out);
  assert_int_equal(out[0], 255);
  assert_int_equal(out[1], 100);
  assert_int_equal(out[2], 0);
  ts_image_channel8(&w16, 0, out);
  assert_int_equal(out[2], 0);
  p[8] = 129; /* 129/257 > 0.5 -> 1 */
  ts_image_channel8(&w16, 0, out);
  assert_int_equal(out[2], 1);
  ts_image_free(&w16);

  ts_image f;
  assert_int_equal(ts_image_alloc(&f, 5, 1, 1, TS_PIX_F32, err), 0);
  const float fv[5] = {0.5f, -3.0f, 7.0f, NAN, 0.25f};
  memcpy(f.pixels, fv, sizeof(fv));
  ts_image_luma8(&f, out); /* one channel: luma is channel 0 */
  const uint8_t wantf[5] = {128, 0, 255, 0, 64};
  assert_memory_equal(out, wantf, 5);
  ts_image_free(&f);

  ts_image h;
  assert_int_equal(ts_image_alloc(&h, 1, 1, 2, TS_PIX_F16, err), 0);
  ((uint16_t *)h.pixels)[0] = 0x3800; /* 0.5 */
  ((uint16_t *)h.pixels)[1] = 0x3c00; /* alpha 1, ignored */
  ts_image_luma8(&h, out);
  assert_int_equal(out[0], 128);
  ts_image_free(&h);

  ts_image g;
  assert_int_equal(ts_image_alloc(&g, 1, 1, 3, TS_PIX_F32, err), 0);
  for (int i = 0; i < 3; i++) ((float *)g.pixels)[i] = 0.5f;
  ts_image_luma8(&g, out);
  assert_int_equal(out[0], 128);
  ts_image_free(&g);
}

static void copy_pixel_copies_all_channels(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  ts_image a, b;
  make_image(&a, 5, 4, 3, TS_PIX_F32);
  assert_int_equal(ts_image_alloc(&b, 7, 6, 3, TS_PIX_F32, err), 0);
  ts_image_copy_pixel(&b, 6, 5, &a, 2, 3);
  for (int c = 0; c < 3; c++)
    assert_true(ts_image_sample(&b, 6, 5, c) == ts_image_sample(&a, 2, 3, c));
  assert_true(ts_image_sample(&b, 5, 5, 0) == 0.0f);
  ts_image_free(&a);
  ts_image_free(&b);
}

/* --- real data ------------------------------------------------------------ */

static void read_real_file(const char *rel, int w, int h, int c) {
  char path[PATH_MAX], err[TS_ERR_LEN];
  snprintf(path, sizeof(path), "%s/%s", ts_test_data_dir(), rel);
  if (access(path, R_OK) != 0)
    fail_msg("%s not found: tests/test-data.sh gets the test images (tests/run-unit.sh runs it), or set "
             "TEXSYN_DATA to a directory holding them", path);
  ts_image img;
  assert_int_equal(ts_image_read(path, &img, NULL, err), 0);
  assert_int_equal(img.width, w);
  assert_int_equal(img.height, h);
  assert_int_equal(img.channels, c);
  assert_int_equal(img.type, TS_PIX_U8);
  uint8_t *luma = malloc((size_t)w * h);
  assert_non_null(luma);
  ts_image_luma8(&img, luma);
  long sum = 0;
  for (int i = 0; i < w * h; i++) sum += luma[i];
  assert_true(sum > 0 && sum < 255L * w * h); /* neither black nor white */
  free(luma);
  ts_image_free(&img);
}

static void real_brick_png(void **state) {
  (void)state;
  read_real_file("textures/brick.png", 512, 512, 1);
}

static void real_aero_jpg(void **state) {
  (void)state;
  read_real_file("aerial/aero1.jpg", 640, 480, 3);
}

#define T(f) cmocka_unit_test_setup_teardown(f, scratch_setup, scratch_teardown)

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(pixtype_sizes_and_names),
    cmocka_unit_test(alloc_checks_arguments),
    T(png8_grey_roundtrip),
    T(png8_rgb_roundtrip),
    T(png8_rgba_roundtrip),
    T(png16_roundtrip),
    T(tiff16_scanline_roundtrip),
    T(tiff16_tiled_read),
    T(jpeg_roundtrip_approx),
    T(jpeg_drops_alpha),
    T(exr_half_roundtrip),
    T(exr_float_roundtrip),
    T(write_converts_types),
    T(geotiff_tags_pass_through),
    T(geotiff_read_bigtiff),
    T(meta_passes_and_filters),
    T(read_missing_file),
    T(read_garbage_file),
    T(read_truncated_png),
    T(read_truncated_jpeg),
    T(read_truncated_exr),
    T(read_truncated_tiff),
    T(read_huge_header_refused),
    T(read_honours_max_pixels),
    T(read_mem_matches_file),
    T(read_refuses_non_images),
    T(probe_reads_the_header_only),
    T(write_unknown_extension),
    T(errors_do_not_leak),
    T(write_into_missing_dir),
    T(write_failure_leaves_no_temp),
    T(write_replaces_atomically),
    cmocka_unit_test(sample_converts_exactly),
    cmocka_unit_test(luma8_known_values),
    cmocka_unit_test(copy_pixel_copies_all_channels),
    cmocka_unit_test(real_brick_png),
    cmocka_unit_test(real_aero_jpg),
};

TS_TEST_MAIN(tests)
