/* gis_gdal.h - what the files of libtexsyn-gis.so share: GDAL set up once,
 * GDAL's error messages into ours. Only common/gis/ includes it (and GDAL's
 * headers); the rest of texsyn sees gis.h. */
#ifndef TS_GIS_GDAL_H
#define TS_GIS_GDAL_H

#include <gdal.h>

#include "gis.h"

/* Registers GDAL's drivers, silences its stderr reports (each failure is
 * reported through err instead) and bounds its block cache, once. */
void ts_gis_init(void);

/* GDAL's last error on this thread, or "no reason given" (never NULL). */
const char *ts_gis_last_error(void);

/* The georeferencing of ds (the file at path) into geo (NULL: nothing).
 * 0, or TS_ETOOBIG for a CRS whose WKT does not fit ts_gis_georef. */
int ts_gis_georef_of(GDALDatasetH ds, const char *path, ts_gis_georef *geo, char *err);

/* Region arguments common to the read functions: w, h > 0, w*h within
 * TS_GIS_MAX_REGION, x + w and y + h within int. 0 or TS_EINVAL. */
int ts_gis_check_region(const char *what, int x, int y, int w, int h, char *err);

#endif
