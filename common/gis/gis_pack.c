/* gis_pack.c - gis.h's vector layer as one file, for sending.
 *
 * A job sent to a coordinator carries each input as one file, and a
 * Shapefile (or a MapInfo TAB, ...) is several: the geometry, its index,
 * the attributes, the projection. Rather than teaching the wire about
 * side files, the client translates such a source into one GeoPackage
 * (GDAL's VectorTranslate, as ogr2ogr -f GPKG): the same features, fields,
 * names and CRS, the coordinates as the same doubles, so the coordinator
 * rasterises the same lines the client would have (test_aerial_gis.py
 * compares the bytes). A source that is one file already is sent as it
 * is. */
#include <cpl_conv.h>
#include <cpl_string.h>
#include <gdal.h>
#include <gdal_utils.h>
#include <stdio.h>

#include "error.h"
#include "gis_gdal.h"

/* The number of files GDAL reads for the dataset. */
static int files_of(GDALDatasetH ds) {
  char **files = GDALGetFileList(ds);
  int n = CSLCount(files);
  CSLDestroy(files);
  return n;
}

static int translate(GDALDatasetH ds, const char *path, const char *to, char *err) {
  char *argv[] = {"-f", "GPKG", NULL};
  GDALVectorTranslateOptions *o = GDALVectorTranslateOptionsNew(argv, NULL);
  if (o == NULL) return ts_error(err, TS_EFORMAT, "%s: cannot translate it: %s", path, ts_gis_last_error());
  int usage = 0;
  GDALDatasetH out = GDALVectorTranslate(to, NULL, 1, &ds, o, &usage);
  GDALVectorTranslateOptionsFree(o);
  if (out == NULL)
    return ts_error(err, TS_EIO, "%s: cannot write it as the GeoPackage %s to send: %s", path, to, ts_gis_last_error());
  GDALClose(out);
  return 0;
}

int ts_gis_vector_single(const char *path, const char *dir, char *out, size_t cap, char *err) {
  ts_gis_init();
  GDALDatasetH ds = GDALOpenEx(path, GDAL_OF_VECTOR | GDAL_OF_READONLY, NULL, NULL, NULL);
  if (ds == NULL) return ts_error(err, TS_EFORMAT, "%s: not a vector source GDAL reads: %s", path, ts_gis_last_error());
  int rc = 0;
  if (files_of(ds) <= 1) snprintf(out, cap, "%s", path);
  else if ((size_t)snprintf(out, cap, "%s/%s.gpkg", dir, CPLGetBasename(path)) >= cap)
    rc = ts_error(err, TS_EINVAL, "%s: the path of its GeoPackage is too long", path);
  else rc = translate(ds, path, out, err);
  GDALClose(ds);
  return rc;
}
