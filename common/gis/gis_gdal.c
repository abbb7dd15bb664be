/* gis_gdal.c - libtexsyn-gis.so's table and what its files share (see
 * gis_gdal.h, and gis_lib.h for why GDAL is a library of its own). */
#include "gis_gdal.h"

#include <cpl_conv.h>
#include <cpl_error.h>
#include <limits.h>
#include <ogr_srs_api.h>
#include <pthread.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "gis_lib.h"

/* GDAL's block cache is process-wide: TS_GIS_CACHE_MB bounds the writer's
 * dirty tiles and the readers' cached blocks together, whatever the
 * scene's size. GDAL's own default (5% of RAM) would be 1.2 GiB on a
 * 24 GiB coordinator, filled by a large write before any block is
 * flushed. The overviews and the COG copy size their buffers by it too:
 * writing a 16384² COG peaked at 548 MiB with 256 MiB of cache and at
 * 215 MiB with 64, and took no longer (bench/gis_write); every put of a
 * tile of the block size completes its blocks, so a bigger cache buys
 * nothing. GDAL_CACHEMAX in the environment still wins (GDAL reads it
 * itself). */
static void init_once(void) {
  GDALAllRegister();
  CPLSetErrorHandler(CPLQuietErrorHandler);
  if (getenv("GDAL_CACHEMAX") == NULL) GDALSetCacheMax64((GIntBig)TS_GIS_CACHE_MB << 20);
}

void ts_gis_init(void) {
  static pthread_once_t once = PTHREAD_ONCE_INIT;
  pthread_once(&once, init_once);
}

const char *ts_gis_last_error(void) {
  const char *m = CPLGetLastErrorMsg();
  return m != NULL && m[0] != '\0' ? m : "no reason given";
}

/* srs as WKT2 into out (len bytes), or as WKT1 if WKT2 does not fit (some
 * CRSs' WKT2 carries a long area of use; WKT1 describes the same CRS for
 * every use here). 0, or the length of the shorter text if neither fits. */
static size_t wkt_of(OGRSpatialReferenceH srs, char *out, size_t len) {
  static const char *const formats[] = {"FORMAT=WKT2_2018", "FORMAT=WKT1_GDAL"};
  size_t shortest = 0;
  for (size_t i = 0; i < sizeof(formats) / sizeof(formats[0]); i++) {
    char *wkt = NULL;
    const char *opts[] = {formats[i], NULL};
    size_t n = OSRExportToWktEx(srs, &wkt, opts) == OGRERR_NONE && wkt != NULL ? strlen(wkt) : 0;
    if (n > 0 && n < len) strcpy(out, wkt);
    CPLFree(wkt);
    if (n > 0 && n < len) return 0;
    if (n > 0 && (shortest == 0 || n < shortest)) shortest = n;
  }
  return shortest > 0 ? shortest : 1;
}

int ts_gis_georef_of(GDALDatasetH ds, const char *path, ts_gis_georef *geo, char *err) {
  if (geo == NULL) return 0;
  memset(geo, 0, sizeof(*geo));
  geo->has_geo = GDALGetGeoTransform(ds, geo->transform) == CE_None;
  if (!geo->has_geo) {
    /* GDAL's identity for an ungeoreferenced raster: map = pixel. */
    double id[6] = {0, 1, 0, 0, 0, 1};
    memcpy(geo->transform, id, sizeof(id));
  }
  OGRSpatialReferenceH srs = GDALGetSpatialRef(ds);
  size_t n = srs != NULL ? wkt_of(srs, geo->crs_wkt, sizeof(geo->crs_wkt)) : 0;
  if (n != 0)
    return ts_error(err, TS_ETOOBIG, "%s: its CRS (%s) takes %zu bytes of WKT, more than the %zu texsyn keeps: "
                    "reproject it (gdalwarp -t_srs)", path, OSRGetName(srs) ? OSRGetName(srs) : "unnamed", n,
                    sizeof(geo->crs_wkt) - 1);
  return 0;
}

int ts_gis_check_region(const char *what, int x, int y, int w, int h, char *err) {
  if (w <= 0 || h <= 0 || (long)w * h > TS_GIS_MAX_REGION)
    return ts_error(err, TS_EINVAL, "%s: region %dx%d: need 1..%ld pixels", what, w, h, TS_GIS_MAX_REGION);
  if ((long)x + w > INT_MAX || (long)y + h > INT_MAX || (long)x < -(long)INT_MAX || (long)y < -(long)INT_MAX)
    return ts_error(err, TS_EINVAL, "%s: region at %d,%d of %dx%d leaves the coordinate range", what, x, y, w, h);
  return 0;
}

static int crs_wkt(const char *definition, char *wkt, size_t len, char *err) {
  ts_gis_init();
  OGRSpatialReferenceH srs = OSRNewSpatialReference(NULL);
  if (srs == NULL) return ts_error(err, TS_ENOMEM, "out of memory for a CRS");
  int rc = 0;
  size_t n;
  CPLErrorReset();
  if (OSRSetFromUserInput(srs, definition) != OGRERR_NONE)
    rc = ts_error(err, TS_EINVAL, "%s is not a CRS GDAL knows (%s): give EPSG:CODE, a PROJ string or WKT",
                  definition, ts_gis_last_error());
  else if ((n = wkt_of(srs, wkt, len)) != 0)
    rc = ts_error(err, TS_ETOOBIG, "%s: its WKT takes %zu bytes, more than the %zu allowed", definition, n,
                  len - 1);
  OSRDestroySpatialReference(srs);
  return rc;
}

__attribute__((visibility("default"))) const ts_gis_lib TS_GIS_LIB_TABLE = {
    ts_gis_raster_open, ts_gis_raster_read,   ts_gis_raster_close,  ts_gis_lines_open,
    ts_gis_lines_read,  ts_gis_lines_info,    ts_gis_lines_close,   ts_gis_writer_create,
    ts_gis_writer_put,  ts_gis_writer_finish, ts_gis_writer_abort, crs_wkt,
    ts_gis_vector_single,
};
