/* gis_raster.c - gis.h's rasters by region: the class map, band 1 of any
 * single-band integer raster GDAL reads, as uint16 class ids. */
#include <cpl_error.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "error.h"
#include "gis_gdal.h"

struct ts_gis_raster {
  pthread_mutex_t lock; /* a GDAL dataset is used by one thread at a time */
  GDALDatasetH ds;
  GDALRasterBandH band;
  GDALDataType type;
  int width, height;
  int has_nodata;
  double nodata;
  char path[4096];
};

/* Byte and UInt16 are read as UInt16 directly; the other integer types
 * through an Int64 buffer whose values are range-checked (UInt64 values
 * past INT64_MAX saturate, and are refused as too large all the same). */
static int integer_type(GDALDataType t) {
  switch (t) {
  case GDT_Byte:
  case GDT_UInt16:
  case GDT_Int16:
  case GDT_UInt32:
  case GDT_Int32:
  case GDT_Int64:
  case GDT_UInt64:
    return 1;
  default:
    return 0;
  }
}

int ts_gis_raster_open(const char *path, ts_gis_raster **out, int *width, int *height, ts_gis_georef *geo,
                       char *err) {
  *out = NULL;
  ts_gis_init();
  struct stat st;
  if (stat(path, &st) != 0)
    return ts_error(err, TS_ENOENT, "%s: no such file: give the class map's path", path);
  if (strlen(path) >= sizeof(((ts_gis_raster *)0)->path))
    return ts_error(err, TS_EINVAL, "%s: the path is too long", path);
  CPLErrorReset();
  GDALDatasetH ds = GDALOpenEx(path, GDAL_OF_RASTER | GDAL_OF_READONLY, NULL, NULL, NULL);
  if (ds == NULL)
    return ts_error(err, TS_EFORMAT, "%s: not a raster GDAL reads (%s)", path, ts_gis_last_error());
  int bands = GDALGetRasterCount(ds), rc = 0;
  GDALDataType type = bands > 0 ? GDALGetRasterDataType(GDALGetRasterBand(ds, 1)) : GDT_Unknown;
  if (bands != 1)
    rc = ts_error(err, TS_EFORMAT, "%s: %d bands: a class map has one band of class ids (save it as a "
                  "single-band raster)", path, bands);
  else if (!integer_type(type))
    rc = ts_error(err, TS_EFORMAT, "%s: its band is of type %s: class ids need an integer type (Byte, UInt16, ...)",
                  path, GDALGetDataTypeName(type));
  if (rc == 0) rc = ts_gis_georef_of(ds, path, geo, err);
  ts_gis_raster *r = rc == 0 ? calloc(1, sizeof(*r)) : NULL;
  if (rc == 0 && r == NULL) rc = ts_error(err, TS_ENOMEM, "%s: out of memory", path);
  if (rc != 0) {
    GDALClose(ds);
    return rc;
  }
  pthread_mutex_init(&r->lock, NULL);
  r->ds = ds;
  r->band = GDALGetRasterBand(ds, 1);
  r->type = type;
  r->width = GDALGetRasterXSize(ds);
  r->height = GDALGetRasterYSize(ds);
  r->nodata = GDALGetRasterNoDataValue(r->band, &r->has_nodata);
  strcpy(r->path, path);
  *width = r->width;
  *height = r->height;
  *out = r;
  return 0;
}

/* The part of the region inside the raster: [*ix, *ix + *iw) etc., and
 * whether there is one. */
static int clip(const ts_gis_raster *r, int x, int y, int w, int h, int *ix, int *iy, int *iw, int *ih) {
  long x0 = x < 0 ? 0 : x, y0 = y < 0 ? 0 : y;
  long x1 = (long)x + w > r->width ? r->width : (long)x + w, y1 = (long)y + h > r->height ? r->height : (long)y + h;
  if (x0 >= x1 || y0 >= y1) return 0;
  *ix = (int)x0, *iy = (int)y0, *iw = (int)(x1 - x0), *ih = (int)(y1 - y0);
  return 1;
}

/* Reads the inside part (ix..) into dst's rows at (ix - x, iy - y). */
static int read_inside(ts_gis_raster *r, int x, int y, int w, int ix, int iy, int iw, int ih, uint16_t *dst,
                       char *err) {
  uint16_t *at = dst + (size_t)(iy - y) * w + (ix - x);
  CPLErrorReset();
  if (r->type == GDT_Byte || r->type == GDT_UInt16) {
    if (GDALRasterIO(r->band, GF_Read, ix, iy, iw, ih, at, iw, ih, GDT_UInt16, 2, (GSpacing)w * 2) != CE_None)
      return ts_error(err, TS_EIO, "%s: reading %dx%d at %d,%d failed: %s", r->path, iw, ih, ix, iy,
                      ts_gis_last_error());
    if (r->has_nodata)
      for (int j = 0; j < ih; j++)
        for (int i = 0; i < iw; i++)
          if (at[(size_t)j * w + i] == r->nodata) at[(size_t)j * w + i] = 0;
    return 0;
  }
  int64_t *buf = malloc((size_t)iw * ih * sizeof(*buf));
  if (buf == NULL) return ts_error(err, TS_ENOMEM, "%s: out of memory reading %dx%d", r->path, iw, ih);
  int rc = 0;
  if (GDALRasterIO(r->band, GF_Read, ix, iy, iw, ih, buf, iw, ih, GDT_Int64, 0, 0) != CE_None)
    rc = ts_error(err, TS_EIO, "%s: reading %dx%d at %d,%d failed: %s", r->path, iw, ih, ix, iy,
                  ts_gis_last_error());
  for (int j = 0; rc == 0 && j < ih; j++)
    for (int i = 0; i < iw; i++) {
      int64_t v = buf[(size_t)j * iw + i];
      if (r->has_nodata && (double)v == r->nodata) v = 0;
      if (v < 0 || v > 65535) {
        rc = ts_error(err, TS_ETOOBIG, "%s: pixel %d,%d holds %lld: class ids are 0..65535", r->path, ix + i,
                      iy + j, (long long)v);
        break;
      }
      at[(size_t)j * w + i] = (uint16_t)v;
    }
  free(buf);
  return rc;
}

int ts_gis_raster_read(ts_gis_raster *r, int x, int y, int w, int h, uint16_t *dst, char *err) {
  int rc = ts_gis_check_region(r->path, x, y, w, h, err);
  if (rc != 0) return rc;
  int ix, iy, iw, ih;
  int inside = clip(r, x, y, w, h, &ix, &iy, &iw, &ih);
  if (!inside || iw < w || ih < h) memset(dst, 0, (size_t)w * h * sizeof(*dst));
  if (!inside) return 0;
  pthread_mutex_lock(&r->lock);
  rc = read_inside(r, x, y, w, ix, iy, iw, ih, dst, err);
  pthread_mutex_unlock(&r->lock);
  return rc;
}

void ts_gis_raster_close(ts_gis_raster *r) {
  if (r == NULL) return;
  GDALClose(r->ds);
  pthread_mutex_destroy(&r->lock);
  free(r);
}
