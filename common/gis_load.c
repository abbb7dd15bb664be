/* gis_load.c - gis.h's GDAL functions in the programs: each loads
 * libtexsyn-gis.so on first use and forwards through its table (gis_lib.h
 * says why GDAL is a library of its own, dl_lib.h where it is looked for).
 * Closing and aborting a handle need no load: a handle exists only once
 * the library has loaded. */
#include "dl_lib.h"
#include "error.h"
#include "gis.h"
#include "gis_lib.h"

static ts_dl_lib gis_lib = {TS_GIS_LIB_NAME, TS_GIS_LIB_ENV, TS_GIS_LIB_TABLE_NAME, "GIS library (GDAL)"};
/* The table, valid once ts_gis_lib_load returned 0. */
#define gis_table ((const ts_gis_lib *)gis_lib.table)

int ts_gis_lib_load(char *err) { return ts_dl_lib_load(&gis_lib, err); }

int ts_gis_raster_open(const char *path, ts_gis_raster **out, int *width, int *height, ts_gis_georef *geo,
                       char *err) {
  *out = NULL;
  int rc = ts_gis_lib_load(err);
  return rc != 0 ? rc : gis_table->raster_open(path, out, width, height, geo, err);
}

int ts_gis_raster_read(ts_gis_raster *r, int x, int y, int w, int h, uint16_t *dst, char *err) {
  return gis_table->raster_read(r, x, y, w, h, dst, err);
}

void ts_gis_raster_close(ts_gis_raster *r) {
  if (r != NULL) gis_table->raster_close(r);
}

int ts_gis_lines_open(const char *path, const ts_gis_georef *scene, int width, int height,
                      const ts_gis_line_rules *rules, ts_gis_lines **out, char *err) {
  *out = NULL;
  int rc = ts_gis_lib_load(err);
  return rc != 0 ? rc : gis_table->lines_open(path, scene, width, height, rules, out, err);
}

int ts_gis_lines_read(ts_gis_lines *l, int x, int y, int w, int h, uint8_t *dst, char *err) {
  return gis_table->lines_read(l, x, y, w, h, dst, err);
}

void ts_gis_lines_info(const ts_gis_lines *l, int *nfeatures, int *reprojected) {
  gis_table->lines_info(l, nfeatures, reprojected);
}

void ts_gis_lines_close(ts_gis_lines *l) {
  if (l != NULL) gis_table->lines_close(l);
}

int ts_gis_writer_create(const char *path, int width, int height, int channels, int tile, const ts_gis_georef *geo,
                         int cog, ts_gis_writer **out, char *err) {
  *out = NULL;
  int rc = ts_gis_lib_load(err);
  return rc != 0 ? rc : gis_table->writer_create(path, width, height, channels, tile, geo, cog, out, err);
}

int ts_gis_writer_put(ts_gis_writer *w, int x, int y, int rw, int rh, const uint8_t *px, char *err) {
  return gis_table->writer_put(w, x, y, rw, rh, px, err);
}

int ts_gis_writer_finish(ts_gis_writer *w, char *err) { return gis_table->writer_finish(w, err); }

void ts_gis_writer_abort(ts_gis_writer *w) {
  if (w != NULL) gis_table->writer_abort(w);
}

int ts_gis_crs_wkt(const char *definition, char *wkt, size_t len, char *err) {
  int rc = ts_gis_lib_load(err);
  return rc != 0 ? rc : gis_table->crs_wkt(definition, wkt, len, err);
}

int ts_gis_vector_single(const char *path, const char *dir, char *out, size_t cap, char *err) {
  int rc = ts_gis_lib_load(err);
  return rc != 0 ? rc : gis_table->vector_single(path, dir, out, cap, err);
}
