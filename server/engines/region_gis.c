/* region_gis.c - region.h's source and sink on GDAL (gis.h), and the
 * choice between them and the image library's (region_file.c).
 *
 * Which library reads a class map: GDAL first for .tif and .tiff, since a
 * GeoTIFF's georeferencing and CRS are GDAL's to read and to pass on, and
 * GDAL reads any tiled or striped TIFF by regions; the image library for
 * every other extension (PNG, EXR, JPEG: what it reads by regions today),
 * and for a TIFF GDAL refuses (more than one band, floating-point samples)
 * or when libtexsyn-gis.so cannot be loaded, so a machine without GDAL
 * reads what it read before. Which writes the image: GDAL for .tif and
 * .tiff (a tiled DEFLATE GeoTIFF, BigTIFF when large, a COG on request),
 * the image library for EXR, PNG and JPEG. */
#include <stdlib.h>
#include <string.h>
#include <strings.h>

#include "error.h"
#include "gis.h"
#include "jobspec.h"
#include "region.h"

int ts_region_is_tiff(const char *path) {
  const char *e = ts_path_ext(path);
  return strcasecmp(e, "tif") == 0 || strcasecmp(e, "tiff") == 0;
}

/* ---- the class map through GDAL ------------------------------------------- */

typedef struct {
  ts_region_source ops;
  ts_gis_raster *r;
  ts_gis_georef geo;
  uint16_t *scratch; /* the ids of the last read */
  size_t cap;        /* its pixels */
} gis_source;

static int gis_read(ts_region_source *s, int x, int y, int w, int h, int32_t *dst, char *err) {
  gis_source *g = (gis_source *)s;
  size_t n = (size_t)w * (size_t)h;
  if (n > g->cap) {
    free(g->scratch);
    g->cap = 0;
    if ((g->scratch = malloc(n * sizeof(uint16_t))) == NULL)
      return ts_error(err, TS_ENOMEM, "out of memory reading a region");
    g->cap = n;
  }
  int rc = ts_gis_raster_read(g->r, x, y, w, h, g->scratch, err);
  for (size_t i = 0; rc == 0 && i < n; i++) dst[i] = g->scratch[i];
  return rc;
}

static void gis_close(ts_region_source *s) {
  gis_source *g = (gis_source *)s;
  ts_gis_raster_close(g->r);
  free(g->scratch);
  free(g);
}

static int gis_source_open(const char *path, ts_region_source **out, char *err) {
  gis_source *g = calloc(1, sizeof(*g));
  if (g == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  int w, h, rc = ts_gis_raster_open(path, &g->r, &w, &h, &g->geo, err);
  if (rc != 0) {
    free(g);
    return rc;
  }
  g->ops = (ts_region_source){w, h, gis_read, gis_close, g->geo.has_geo || g->geo.crs_wkt[0] ? &g->geo : NULL};
  *out = &g->ops;
  return 0;
}

/* The metadata the image library reads from path, for an output it
 * writes (an OpenEXR keeps a GeoTIFF's tags as attributes); none if it
 * cannot read the file, which GDAL could. */
static int image_meta(const char *path, ts_meta **meta) {
  if (meta == NULL) return 0;
  ts_region_source *s;
  char why[TS_ERR_LEN];
  if (ts_region_source_open_image(path, meta, &s, why) == 0) s->close(s);
  return 0;
}

int ts_region_source_open(const char *path, ts_meta **meta, ts_region_source **out, char *err) {
  *out = NULL;
  if (meta != NULL) *meta = NULL;
  if (ts_region_is_tiff(path)) {
    int rc = gis_source_open(path, out, err);
    /* A TIFF GDAL takes for no class map, or no GDAL: the image library's. */
    if (rc != TS_EFORMAT && rc != TS_ENOTSUP) return rc == 0 ? image_meta(path, meta) : rc;
  }
  return ts_region_source_open_image(path, meta, out, err);
}

/* ---- vector lines through GDAL ---------------------------------------------- */

typedef struct {
  ts_region_source ops;
  ts_gis_lines *l;
  uint8_t *scratch; /* the values of the last read */
  size_t cap;       /* its pixels */
} lines_source;

static int lines_read(ts_region_source *s, int x, int y, int w, int h, int32_t *dst, char *err) {
  lines_source *l = (lines_source *)s;
  size_t n = (size_t)w * (size_t)h;
  if (n > l->cap) {
    free(l->scratch);
    l->cap = 0;
    if ((l->scratch = malloc(n)) == NULL) return ts_error(err, TS_ENOMEM, "out of memory reading a region");
    l->cap = n;
  }
  int rc = ts_gis_lines_read(l->l, x, y, w, h, l->scratch, err);
  for (size_t i = 0; rc == 0 && i < n; i++) dst[i] = l->scratch[i];
  return rc;
}

static void lines_close(ts_region_source *s) {
  lines_source *l = (lines_source *)s;
  ts_gis_lines_close(l->l);
  free(l->scratch);
  free(l);
}

int ts_region_source_open_lines(const char *path, const ts_region_source *scene, const ts_gis_line_rules *rules,
                                ts_region_source **out, char *err) {
  *out = NULL;
  lines_source *l = calloc(1, sizeof(*l));
  if (l == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  int rc = ts_gis_lines_open(path, scene->geo, scene->width, scene->height, rules, &l->l, err);
  if (rc != 0) {
    free(l);
    return rc;
  }
  l->ops = (ts_region_source){scene->width, scene->height, lines_read, lines_close, scene->geo};
  *out = &l->ops;
  return 0;
}

/* ---- the image through GDAL ------------------------------------------------- */

typedef struct {
  ts_tile_sink ops;
  ts_gis_writer *w;
} gis_sink;

static int gis_put(ts_tile_sink *s, int x, int y, int w, int h, const uint8_t *rgb, char *err) {
  return ts_gis_writer_put(((gis_sink *)s)->w, x, y, w, h, rgb, err);
}

static int gis_finish(ts_tile_sink *s, char *err) {
  int rc = ts_gis_writer_finish(((gis_sink *)s)->w, err);
  free(s);
  return rc;
}

static void gis_abort(ts_tile_sink *s) {
  if (s == NULL) return;
  ts_gis_writer_abort(((gis_sink *)s)->w);
  free(s);
}

int ts_tile_sink_open(const char *path, int w, int h, int tile, const ts_region_source *from, const ts_meta *meta_from,
                      int cog, ts_tile_sink **out, char *err) {
  *out = NULL;
  if (!ts_region_is_tiff(path)) {
    if (cog) return ts_error(err, TS_EINVAL, "%s: --cog writes a Cloud-Optimised GeoTIFF: name the output .tif", path);
    return ts_tile_sink_open_image(path, w, h, tile, meta_from, out, err);
  }
  int rc = ts_gis_lib_load(err);
  if (rc == TS_ENOTSUP && !cog) return ts_tile_sink_open_image(path, w, h, tile, meta_from, out, err);
  if (rc != 0) return rc;
  gis_sink *g = calloc(1, sizeof(*g));
  if (g == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  rc = ts_gis_writer_create(path, w, h, 3, tile, from != NULL ? from->geo : NULL, cog, &g->w, err);
  if (rc != 0) {
    free(g);
    return rc;
  }
  g->ops = (ts_tile_sink){gis_put, gis_finish, gis_abort};
  *out = &g->ops;
  return 0;
}
