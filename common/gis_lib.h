/* gis_lib.h - the boundary between the programs and libtexsyn-gis.so.
 *
 * GDAL (gis.h's rasters, vectors and writer; common/gis/) is built into a
 * shared object of its own and loaded with dlopen by gis_load.c on the
 * first GIS call, as image I/O is (image_lib.h, dl_lib.h): GDAL pulls in
 * some 200 shared libraries (PROJ, GEOS, curl, the format libraries) that
 * commands which never read a GIS file (texsyn status, the worker daemon)
 * must not load. The library is C, compiled position-independent with
 * the programs' flags; it exports one symbol of ours, the table below. */
#ifndef TS_GIS_LIB_H
#define TS_GIS_LIB_H

#include "gis.h"

#define TS_GIS_LIB_NAME "libtexsyn-gis.so"
/* Overrides the search with one path (tests, unusual installs). */
#define TS_GIS_LIB_ENV "TEXSYN_GIS_LIB"

/* Each member is the gis.h function of the same name. */
typedef struct {
  int (*raster_open)(const char *path, ts_gis_raster **out, int *width, int *height, ts_gis_georef *geo,
                     char *err);
  int (*raster_read)(ts_gis_raster *r, int x, int y, int w, int h, uint16_t *dst, char *err);
  void (*raster_close)(ts_gis_raster *r);
  int (*lines_open)(const char *path, const ts_gis_georef *scene, int width, int height,
                    const ts_gis_line_rules *rules, ts_gis_lines **out, char *err);
  int (*lines_read)(ts_gis_lines *l, int x, int y, int w, int h, uint8_t *dst, char *err);
  void (*lines_info)(const ts_gis_lines *l, int *nfeatures, int *reprojected);
  void (*lines_close)(ts_gis_lines *l);
  int (*writer_create)(const char *path, int width, int height, int channels, int tile, const ts_gis_georef *geo,
                       int cog, ts_gis_writer **out, char *err);
  int (*writer_put)(ts_gis_writer *w, int x, int y, int rw, int rh, const uint8_t *px, char *err);
  int (*writer_finish)(ts_gis_writer *w, char *err);
  void (*writer_abort)(ts_gis_writer *w);
  int (*crs_wkt)(const char *definition, char *wkt, size_t len, char *err);
  int (*vector_single)(const char *path, const char *dir, char *out, size_t cap, char *err);
} ts_gis_lib;

/* Versioned like image_lib.h's table: change the name with any change to
 * ts_gis_lib or to the structs of gis.h, so that a library built from
 * other sources fails to load instead of being called wrongly. */
#define TS_GIS_LIB_TABLE ts_gis_lib_v2
#define TS_GIS_LIB_STR_(x) #x
#define TS_GIS_LIB_STR(x) TS_GIS_LIB_STR_(x)
#define TS_GIS_LIB_TABLE_NAME TS_GIS_LIB_STR(TS_GIS_LIB_TABLE)

extern const ts_gis_lib TS_GIS_LIB_TABLE;

#endif
