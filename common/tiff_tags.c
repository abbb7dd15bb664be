/* tiff_tags.c - see tiff_tags.h.
 *
 * Every read is bounds-checked against the file size before it is made,
 * and a directory or a tag larger than any sane TIFF holds is corrupt, so
 * bytes from a client can steer neither a read nor an allocation. */
#include "tiff_tags.h"

#include <errno.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/types.h>

#include "error.h"

const ts_geotag ts_geotags[TS_GEOTAG_COUNT] = {
    {33550, TS_TIFF_DOUBLE, "GeoTIFF:ModelPixelScale"},
    {33922, TS_TIFF_DOUBLE, "GeoTIFF:ModelTiePoint"},
    {34264, TS_TIFF_DOUBLE, "GeoTIFF:ModelTransformation"},
    {34735, TS_TIFF_SHORT, "GeoTIFF:GeoKeyDirectory"},
    {34736, TS_TIFF_DOUBLE, "GeoTIFF:GeoDoubleParams"},
    {34737, TS_TIFF_ASCII, "GeoTIFF:GeoAsciiParams"},
    {42112, TS_TIFF_ASCII, "GDAL:Metadata"},
    {42113, TS_TIFF_ASCII, "GDAL:NoData"},
};

/* Sanity bounds: a directory or a tag larger than this is corrupt. */
#define TIFF_MAX_ENTRIES 4096
#define TIFF_MAX_VALUES (1u << 20)
#define TIFF_MAX_ENTRY 20 /* bytes of a BigTIFF directory entry */

static const uint8_t kZeros[8];

/* An open TIFF: byte order ("MM" is big-endian), BigTIFF or classic, the
 * file size and the offset of the first directory. */
typedef struct {
  FILE *f;
  int be, big;
  uint64_t size, ifd;
} tiff;

static size_t tiff_word(const tiff *t) { return t->big ? 8 : 4; }    /* count and offset width */
static size_t tiff_entry(const tiff *t) { return t->big ? 20 : 12; } /* directory entry size */
static size_t tiff_nwidth(const tiff *t) { return t->big ? 8 : 2; }  /* entry count width */

static uint64_t tiff_get(const tiff *t, const uint8_t *p, size_t n) {
  uint64_t v = 0;
  for (size_t i = 0; i < n; i++) v |= (uint64_t)p[t->be ? n - 1 - i : i] << (8 * i);
  return v;
}

static void tiff_put(const tiff *t, uint8_t *p, size_t n, uint64_t v) {
  for (size_t i = 0; i < n; i++) p[t->be ? n - 1 - i : i] = (uint8_t)(v >> (8 * i));
}

static int tiff_pread(const tiff *t, uint64_t off, void *buf, uint64_t n) {
  return off <= t->size && n <= t->size - off && fseeko(t->f, (off_t)off, SEEK_SET) == 0 &&
         fread(buf, 1, n, t->f) == n;
}

static int tiff_pwrite(const tiff *t, uint64_t off, const void *buf, size_t n) {
  return fseeko(t->f, (off_t)off, SEEK_SET) == 0 && fwrite(buf, 1, n, t->f) == n;
}

static int tiff_open(tiff *t, FILE *f) {
  uint8_t h[16];
  t->f = f;
  if (fseeko(f, 0, SEEK_END) != 0) return 0;
  off_t end = ftello(f);
  if (end < 0) return 0;
  t->size = (uint64_t)end;
  if (!tiff_pread(t, 0, h, 8)) return 0;
  if (h[0] == 'I' && h[1] == 'I')
    t->be = 0;
  else if (h[0] == 'M' && h[1] == 'M')
    t->be = 1;
  else
    return 0;
  uint64_t magic = tiff_get(t, h + 2, 2);
  t->big = magic == 43;
  if (magic == 42) {
    t->ifd = tiff_get(t, h + 4, 4);
    return 1;
  }
  if (!t->big || !tiff_pread(t, 0, h, 16) || tiff_get(t, h + 4, 2) != 8 || tiff_get(t, h + 6, 2) != 0)
    return 0;
  t->ifd = tiff_get(t, h + 8, 8);
  return 1;
}

/* The first directory: its n raw entries and the next-directory offset. */
typedef struct {
  uint8_t *entries;
  size_t n;
  uint64_t next;
} tiff_dir;

/* 0, TS_EFORMAT (unreadable) or TS_ENOMEM; entries are malloc'd. */
static int tiff_read_dir(const tiff *t, tiff_dir *d) {
  size_t cw = tiff_nwidth(t), w = tiff_word(t);
  uint8_t b[8];
  if (!tiff_pread(t, t->ifd, b, cw)) return TS_EFORMAT;
  uint64_t n = tiff_get(t, b, cw);
  if (n == 0 || n > TIFF_MAX_ENTRIES) return TS_EFORMAT;
  size_t len = (size_t)n * tiff_entry(t);
  d->entries = malloc(len);
  if (d->entries == NULL) return TS_ENOMEM;
  d->n = (size_t)n;
  if (!tiff_pread(t, t->ifd + cw, d->entries, len) || !tiff_pread(t, t->ifd + cw + len, b, w)) {
    free(d->entries);
    d->entries = NULL;
    return TS_EFORMAT;
  }
  d->next = tiff_get(t, b, w);
  return 0;
}

static const ts_geotag *geotag_numbered(uint64_t tag) {
  for (int i = 0; i < TS_GEOTAG_COUNT; i++)
    if (ts_geotags[i].tag == tag) return &ts_geotags[i];
  return NULL;
}

const ts_geotag *ts_geotag_named(const char *name) {
  for (int i = 0; i < TS_GEOTAG_COUNT; i++)
    if (strcasecmp(name, ts_geotags[i].name) == 0) return &ts_geotags[i];
  return NULL;
}

static size_t geo_value_size(uint16_t type) {
  return type == TS_TIFF_DOUBLE ? 8 : type == TS_TIFF_SHORT ? 2 : 1;
}

/* Reverses the bytes of each of the count values (size bytes each) when
 * the file's byte order is not the host's: file order to host order, and
 * back. */
static void geo_swap(const tiff *t, uint8_t *data, size_t count, size_t size) {
  if (t->be == (__BYTE_ORDER__ == __ORDER_BIG_ENDIAN__)) return;
  for (uint8_t *p = data; p < data + count * size; p += size)
    for (size_t i = 0; i < size / 2; i++) {
      uint8_t c = p[i];
      p[i] = p[size - 1 - i];
      p[size - 1 - i] = c;
    }
}

/* The values of directory entry e, size bytes each, inline or at their
 * offset, into out in host order. 0, TS_EFORMAT or TS_ENOMEM. */
static int geo_values(const tiff *t, const uint8_t *e, size_t size, ts_geo_value *out) {
  size_t w = tiff_word(t);
  uint64_t count = tiff_get(t, e + 4, w);
  if (count == 0 || count > TIFF_MAX_VALUES) return TS_EFORMAT;
  size_t len = (size_t)count * size;
  uint8_t *v = malloc(len);
  if (v == NULL) return TS_ENOMEM;
  const uint8_t *field = e + 4 + w;
  if (len <= w) {
    memcpy(v, field, len);
  } else if (!tiff_pread(t, tiff_get(t, field, w), v, len)) {
    free(v);
    return TS_EFORMAT;
  }
  geo_swap(t, v, (size_t)count, size);
  *out = (ts_geo_value){(size_t)count, v};
  return 0;
}

void ts_geo_free(ts_geo_value tags[TS_GEOTAG_COUNT]) {
  for (int i = 0; i < TS_GEOTAG_COUNT; i++) {
    free((void *)tags[i].values);
    tags[i] = (ts_geo_value){0, NULL};
  }
}

int ts_geo_read(FILE *f, ts_geo_value tags[TS_GEOTAG_COUNT]) {
  memset(tags, 0, TS_GEOTAG_COUNT * sizeof(*tags));
  tiff t;
  tiff_dir d = {0};
  if (!tiff_open(&t, f)) return 0;
  int rc = tiff_read_dir(&t, &d);
  if (rc != 0) return rc == TS_ENOMEM ? rc : 0;
  for (size_t i = 0; rc == 0 && i < d.n; i++) {
    const uint8_t *e = d.entries + i * tiff_entry(&t);
    const ts_geotag *g = geotag_numbered(tiff_get(&t, e, 2));
    if (g == NULL || tiff_get(&t, e + 2, 2) != g->type) continue;
    ts_geo_value v;
    int vrc = geo_values(&t, e, geo_value_size(g->type), &v);
    if (vrc == TS_ENOMEM) rc = vrc;
    if (vrc != 0) continue; /* a malformed tag is skipped */
    ts_geo_value *slot = &tags[g - ts_geotags]; /* the last of a repeated tag wins */
    free((void *)slot->values);
    *slot = v;
  }
  free(d.entries);
  if (rc != 0) ts_geo_free(tags);
  return rc;
}

/* A directory entry in file order, and its tag for sorting. */
typedef struct {
  uint16_t tag;
  uint8_t bytes[TIFF_MAX_ENTRY];
} dir_entry;

static int by_tag(const void *a, const void *b) {
  uint16_t x = ((const dir_entry *)a)->tag, y = ((const dir_entry *)b)->tag;
  return (x > y) - (x < y);
}

/* Copies d's entries, less any GeoTIFF ones, into out; their count. */
static size_t geo_kept_entries(const tiff *t, const tiff_dir *d, dir_entry *out) {
  size_t n = 0, es = tiff_entry(t);
  for (size_t i = 0; i < d->n; i++) {
    const uint8_t *e = d->entries + i * es;
    uint16_t tag = (uint16_t)tiff_get(t, e, 2);
    if (geotag_numbered(tag) != NULL) continue;
    out[n].tag = tag;
    memcpy(out[n++].bytes, e, es);
  }
  return n;
}

/* Writes count values of size bytes (host order, at v) at off, in file
 * order, a chunk at a time. */
static int geo_write_values(const tiff *t, uint64_t off, const uint8_t *v, size_t count, size_t size) {
  if (fseeko(t->f, (off_t)off, SEEK_SET) != 0) return 0;
  uint8_t chunk[4096];
  size_t per = sizeof(chunk) / size;
  for (size_t i = 0; i < count; i += per) {
    size_t k = count - i < per ? count - i : per;
    memcpy(chunk, v + i * size, k * size);
    geo_swap(t, chunk, k, size);
    if (fwrite(chunk, 1, k * size, t->f) != k * size) return 0;
  }
  return 1;
}

/* Fills e for the values v of g: inline if they fit the entry, else
 * written at *pos, which moves past them to the next word. Writes only
 * while ok (a write failed before if not); returns ok after its own. */
static int geo_entry(const tiff *t, const ts_geotag *g, const ts_geo_value *v, int ok, uint64_t *pos,
                     dir_entry *e) {
  size_t w = tiff_word(t), size = geo_value_size(g->type), len = v->count * size;
  memset(e, 0, sizeof(*e));
  e->tag = g->tag;
  tiff_put(t, e->bytes, 2, g->tag);
  tiff_put(t, e->bytes + 2, 2, g->type);
  tiff_put(t, e->bytes + 4, w, v->count);
  uint8_t *field = e->bytes + 4 + w;
  if (len <= w) {
    memcpy(field, v->values, len);
    geo_swap(t, field, v->count, size);
    return ok;
  }
  tiff_put(t, field, w, *pos);
  uint64_t end = *pos + len;
  ok = ok && geo_write_values(t, *pos, v->values, v->count, size);
  *pos = (end + 7) & ~(uint64_t)7;
  return ok && tiff_pwrite(t, end, kZeros, *pos - end);
}

/* Writes the directory of n entries (and next) at pos, then points the
 * header at it. */
static int tiff_write_dir(const tiff *t, const dir_entry *e, size_t n, uint64_t next, uint64_t pos) {
  size_t cw = tiff_nwidth(t), w = tiff_word(t), es = tiff_entry(t);
  uint8_t b[8];
  tiff_put(t, b, cw, n);
  int ok = tiff_pwrite(t, pos, b, cw);
  for (size_t i = 0; ok && i < n; i++) ok = fwrite(e[i].bytes, 1, es, t->f) == es;
  tiff_put(t, b, w, next);
  ok = ok && fwrite(b, 1, w, t->f) == w;
  tiff_put(t, b, w, pos);
  return ok && tiff_pwrite(t, t->big ? 8 : 4, b, w);
}

/* Appends tags' values and the new first directory to the end of t. */
static int geo_append(const tiff *t, const tiff_dir *d, const ts_geo_value tags[TS_GEOTAG_COUNT], char *why) {
  dir_entry *e = malloc((d->n + TS_GEOTAG_COUNT) * sizeof(*e));
  if (e == NULL) return ts_error(why, TS_ENOMEM, "out of memory");
  /* Old entries minus any of ours, then ours; sorted by tag as TIFF wants. */
  size_t n = geo_kept_entries(t, d, e);
  uint64_t pos = (t->size + 7) & ~(uint64_t)7; /* word-aligned append */
  int ok = tiff_pwrite(t, t->size, kZeros, pos - t->size);
  for (int i = 0; i < TS_GEOTAG_COUNT; i++)
    if (tags[i].values != NULL && tags[i].count > 0 && tags[i].count <= TIFF_MAX_VALUES)
      ok = geo_entry(t, &ts_geotags[i], &tags[i], ok, &pos, &e[n++]);
  qsort(e, n, sizeof(*e), by_tag);
  uint64_t dir_len = tiff_nwidth(t) + n * tiff_entry(t) + tiff_word(t);
  int rc = 0;
  if (!t->big && pos + dir_len > UINT32_MAX)
    rc = ts_error(why, TS_ETOOBIG, "GeoTIFF tags would push the file past the 4 GiB classic TIFF limit");
  else if (!ok || !tiff_write_dir(t, e, n, d->next, pos))
    rc = ts_error(why, TS_EIO, "%s", strerror(errno));
  free(e);
  return rc;
}

int ts_geo_write(const char *path, const ts_geo_value tags[TS_GEOTAG_COUNT], char *why) {
  FILE *f = fopen(path, "r+b");
  if (f == NULL) return ts_error(why, TS_EIO, "%s", strerror(errno));
  tiff t;
  tiff_dir d = {0};
  int rc = tiff_open(&t, f) ? tiff_read_dir(&t, &d) : TS_EFORMAT;
  if (rc == 0)
    rc = geo_append(&t, &d, tags, why);
  else if (rc == TS_EFORMAT)
    ts_error(why, rc, "cannot parse the TIFF directory to add GeoTIFF tags");
  else
    ts_error(why, rc, "out of memory");
  free(d.entries);
  if (fclose(f) != 0 && rc == 0) rc = ts_error(why, TS_EIO, "%s", strerror(errno));
  return rc;
}
