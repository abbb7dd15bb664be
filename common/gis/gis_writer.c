/* gis_writer.c - gis.h's output by regions: a tiled GeoTIFF written tile
 * by tile through GDAL's RasterIO, never held whole, then optionally made
 * a Cloud-Optimised GeoTIFF.
 *
 * The pixels go to PATH.part as they come; GDAL's block cache (bounded in
 * gis_gdal.c) holds the blocks not yet complete, so with the engine's
 * tile as the block size every put completes its blocks and memory stays
 * at the cache bound whatever the scene's size. finish then either
 * renames PATH.part to PATH (a plain tiled GeoTIFF, DEFLATE with the
 * horizontal predictor), or, for a COG:
 *   1. builds the overviews inside PATH.part (averaged, each level half
 *      the previous, down to one tile): GDAL reads the full resolution
 *      back block by block;
 *   2. copies PATH.part through GDAL's COG driver into PATH.cog.part with
 *      OVERVIEWS=FORCE_USE_EXISTING: the driver only reorders (overviews
 *      first, tiles in order, the ghost header) and recompresses; it would
 *      otherwise build the overviews itself in a temporary file, the same
 *      work (GDAL's COG driver documentation);
 *   3. renames PATH.cog.part to PATH and removes PATH.part.
 * So that the work is not compressed twice at full strength, PATH.part of
 * a COG is ZSTD at level 1 (fast, and read only once more). */
#include <cpl_conv.h>
#include <cpl_error.h>
#include <cpl_string.h>
#include <limits.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "error.h"
#include "gis_gdal.h"

struct ts_gis_writer {
  pthread_mutex_t lock;
  GDALDatasetH ds;
  int width, height, channels, tile, cog;
  char path[PATH_MAX], part[PATH_MAX + 16], cog_part[PATH_MAX + 16];
};

/* The creation options of PATH.part. */
static char **part_options(int channels, int tile, int cog) {
  char **o = NULL;
  o = CSLSetNameValue(o, "TILED", "YES");
  o = CSLSetNameValue(o, "BLOCKXSIZE", CPLSPrintf("%d", tile));
  o = CSLSetNameValue(o, "BLOCKYSIZE", CPLSPrintf("%d", tile));
  o = CSLSetNameValue(o, "INTERLEAVE", "PIXEL");
  /* IF_SAFER: BigTIFF when the file might pass 4 GiB; the compressed size
   * being unknown until the end, GDAL 3.6 takes BigTIFF from about 2 GB of
   * uncompressed pixels on (1647 MiB gave classic TIFF, 1934 MiB BigTIFF). */
  o = CSLSetNameValue(o, "BIGTIFF", "IF_SAFER");
  /* A tile never put is left out of the file and reads as 0, rather than
   * compressed as zeros at close. */
  o = CSLSetNameValue(o, "SPARSE_OK", "TRUE");
  if (cog) {
    o = CSLSetNameValue(o, "COMPRESS", "ZSTD");
    o = CSLSetNameValue(o, "ZSTD_LEVEL", "1");
  } else {
    o = CSLSetNameValue(o, "COMPRESS", "DEFLATE");
    o = CSLSetNameValue(o, "PREDICTOR", "2");
  }
  if (channels >= 3) o = CSLSetNameValue(o, "PHOTOMETRIC", "RGB");
  if (channels == 4) o = CSLSetNameValue(o, "ALPHA", "YES");
  return o;
}

static int set_georef(ts_gis_writer *w, const ts_gis_georef *geo, char *err) {
  if (geo == NULL) return 0;
  CPLErrorReset();
  if (geo->has_geo && GDALSetGeoTransform(w->ds, (double *)geo->transform) != CE_None)
    return ts_error(err, TS_EIO, "%s: cannot set its georeferencing: %s", w->part, ts_gis_last_error());
  if (geo->crs_wkt[0] != '\0' && GDALSetProjection(w->ds, geo->crs_wkt) != CE_None)
    return ts_error(err, TS_EFORMAT, "%s: cannot set its CRS (%s): %s", w->part, geo->crs_wkt,
                    ts_gis_last_error());
  return 0;
}

static int check_create(const char *path, int width, int height, int channels, int tile, char *err) {
  if (width <= 0 || height <= 0)
    return ts_error(err, TS_EINVAL, "%s: size %dx%d: need at least 1x1", path, width, height);
  if (channels < 1 || channels > 4)
    return ts_error(err, TS_EINVAL, "%s: %d channels: need 1..4 (3 for RGB)", path, channels);
  if (tile < 16 || tile > 4096 || tile % 16 != 0)
    return ts_error(err, TS_EINVAL, "%s: tile %d: a GeoTIFF's tiles are 16..4096 pixels, a multiple of 16", path,
                    tile);
  if (strlen(path) >= PATH_MAX) return ts_error(err, TS_EINVAL, "%s: the path is too long", path);
  return 0;
}

int ts_gis_writer_create(const char *path, int width, int height, int channels, int tile, const ts_gis_georef *geo,
                         int cog, ts_gis_writer **out, char *err) {
  *out = NULL;
  int rc = check_create(path, width, height, channels, tile, err);
  if (rc != 0) return rc;
  ts_gis_init();
  ts_gis_writer *w = calloc(1, sizeof(*w));
  if (w == NULL) return ts_error(err, TS_ENOMEM, "%s: out of memory", path);
  pthread_mutex_init(&w->lock, NULL);
  w->width = width, w->height = height, w->channels = channels, w->tile = tile, w->cog = cog != 0;
  strcpy(w->path, path);
  snprintf(w->part, sizeof(w->part), "%s.part", path);
  snprintf(w->cog_part, sizeof(w->cog_part), "%s.cog.part", path);
  GDALDriverH gtiff = GDALGetDriverByName("GTiff");
  char **opts = part_options(channels, tile, w->cog);
  CPLErrorReset();
  w->ds = gtiff != NULL ? GDALCreate(gtiff, w->part, width, height, channels, GDT_Byte, opts) : NULL;
  CSLDestroy(opts);
  if (w->ds == NULL)
    rc = ts_error(err, TS_EIO, "%s: cannot create it: %s (is the directory there and writable?)", w->part,
                  ts_gis_last_error());
  else
    rc = set_georef(w, geo, err);
  if (rc != 0) {
    ts_gis_writer_abort(w);
    return rc;
  }
  *out = w;
  return 0;
}

int ts_gis_writer_put(ts_gis_writer *w, int x, int y, int rw, int rh, const uint8_t *px, char *err) {
  if (rw <= 0 || rh <= 0 || x < 0 || y < 0 || x > w->width - rw || y > w->height - rh || px == NULL)
    return ts_error(err, TS_EINVAL, "%s: region %dx%d at %d,%d is not inside the %dx%d image", w->path, rw, rh, x,
                    y, w->width, w->height);
  pthread_mutex_lock(&w->lock);
  CPLErrorReset();
  int c = w->channels;
  CPLErr e = GDALDatasetRasterIO(w->ds, GF_Write, x, y, rw, rh, (void *)px, rw, rh, GDT_Byte, c, NULL, c,
                                 (GSpacing)rw * c, 1);
  int rc = e == CE_None ? 0
                        : ts_error(err, TS_EIO, "%s: writing %dx%d at %d,%d failed: %s (is the disk full?)", w->part,
                                   rw, rh, x, y, ts_gis_last_error());
  pthread_mutex_unlock(&w->lock);
  return rc;
}

/* Overviews halving down to one tile, inside PATH.part. */
static int build_overviews(ts_gis_writer *w, char *err) {
  int levels[32], n = 0;
  for (int f = 2; n < 32 && (w->width > w->tile * (f / 2) || w->height > w->tile * (f / 2)); f *= 2)
    levels[n++] = f;
  if (n == 0) return 0;
  CPLSetThreadLocalConfigOption("COMPRESS_OVERVIEW", "ZSTD");
  CPLErrorReset();
  CPLErr e = GDALBuildOverviews(w->ds, "AVERAGE", n, levels, 0, NULL, NULL, NULL);
  CPLSetThreadLocalConfigOption("COMPRESS_OVERVIEW", NULL);
  if (e != CE_None)
    return ts_error(err, TS_EIO, "%s: building its overviews failed: %s (is the disk full?)", w->part,
                    ts_gis_last_error());
  return 0;
}

/* PATH.part (with overviews) through the COG driver into PATH.cog.part. */
static int copy_cog(ts_gis_writer *w, char *err) {
  GDALDriverH cogd = GDALGetDriverByName("COG");
  if (cogd == NULL)
    return ts_error(err, TS_ENOTSUP, "%s: this GDAL has no COG driver (GDAL 3.1 or later needed)", w->path);
  char **o = NULL;
  int block = w->tile >= 128 ? w->tile : 512;
  o = CSLSetNameValue(o, "BLOCKSIZE", CPLSPrintf("%d", block));
  o = CSLSetNameValue(o, "COMPRESS", "DEFLATE");
  o = CSLSetNameValue(o, "PREDICTOR", "YES");
  o = CSLSetNameValue(o, "OVERVIEW_COMPRESS", "DEFLATE");
  o = CSLSetNameValue(o, "OVERVIEW_PREDICTOR", "YES");
  o = CSLSetNameValue(o, "OVERVIEWS", w->width > block || w->height > block ? "FORCE_USE_EXISTING" : "NONE");
  o = CSLSetNameValue(o, "BIGTIFF", "IF_SAFER");
  CPLErrorReset();
  GDALDatasetH cog = GDALCreateCopy(cogd, w->cog_part, w->ds, FALSE, o, NULL, NULL);
  CSLDestroy(o);
  if (cog == NULL)
    return ts_error(err, TS_EIO, "%s: writing the Cloud-Optimised GeoTIFF failed: %s (is the disk full?)",
                    w->cog_part, ts_gis_last_error());
  CPLErrorReset();
  GDALClose(cog);
  if (CPLGetLastErrorType() >= CE_Failure)
    return ts_error(err, TS_EIO, "%s: closing it failed: %s", w->cog_part, ts_gis_last_error());
  return 0;
}

static int finish(ts_gis_writer *w, char *err) {
  CPLErrorReset();
  GDALFlushCache(w->ds);
  if (CPLGetLastErrorType() >= CE_Failure)
    return ts_error(err, TS_EIO, "%s: writing its last tiles failed: %s (is the disk full?)", w->part,
                    ts_gis_last_error());
  int rc = 0;
  if (w->cog && (rc = build_overviews(w, err)) == 0) rc = copy_cog(w, err);
  CPLErrorReset();
  GDALClose(w->ds);
  w->ds = NULL;
  if (rc == 0 && CPLGetLastErrorType() >= CE_Failure)
    rc = ts_error(err, TS_EIO, "%s: closing it failed: %s", w->part, ts_gis_last_error());
  if (rc != 0) return rc;
  const char *from = w->cog ? w->cog_part : w->part;
  if (rename(from, w->path) != 0)
    return ts_error(err, TS_EIO, "cannot rename %s to %s: %m", from, w->path);
  if (w->cog) unlink(w->part);
  return 0;
}

int ts_gis_writer_finish(ts_gis_writer *w, char *err) {
  pthread_mutex_lock(&w->lock);
  int rc = finish(w, err);
  pthread_mutex_unlock(&w->lock);
  if (rc != 0) ts_gis_writer_abort(w);
  else {
    pthread_mutex_destroy(&w->lock);
    free(w);
  }
  return rc;
}

void ts_gis_writer_abort(ts_gis_writer *w) {
  if (w == NULL) return;
  if (w->ds != NULL) GDALClose(w->ds);
  unlink(w->part);
  unlink(w->cog_part);
  pthread_mutex_destroy(&w->lock);
  free(w);
}
