/* region.h - rasters too large to hold whole: a "region source" read a
 * region at a time (a tiled scene's class map and line raster) and a "tile
 * sink" written a band at a time (its output), so an engine's memory
 * follows the tiles in flight, not the scene.
 *
 * Both are small operation tables, so other implementations plug in beside
 * the image library's (region_file.c, OpenImageIO): a GDAL raster read by
 * regions with its georeferencing, vector roads rasterised by regions, a
 * Cloud-Optimised GeoTIFF writer - each a few lines wrapping its own
 * open/read/put/finish calls in these tables. */
#ifndef TS_REGION_H
#define TS_REGION_H

#include <stdint.h>

#include "image.h"

/* Values outside 0..TS_REGION_MAX_VALUE read as -1 (floats are rounded). */
#define TS_REGION_MAX_VALUE 65535

typedef struct ts_region_source ts_region_source;
struct ts_region_source {
  int width, height;
  /* The integer value of the first channel of every pixel of
   * [x, x + w) x [y, y + h) (inside the raster), row-major into dst: a
   * class id or a line value, floats rounded; -1 for a value outside
   * 0..TS_REGION_MAX_VALUE. 0, or an error naming the file. */
  int (*read)(ts_region_source *s, int x, int y, int w, int h, int32_t *dst, char *err);
  void (*close)(ts_region_source *s); /* frees s */
};

typedef struct ts_tile_sink ts_tile_sink;
struct ts_tile_sink {
  /* 8-bit RGB pixels of [x, x + w) x [y, y + h), interleaved, row-major.
   * The engine hands whole-width bands, top to bottom, each once, every
   * band but the last a multiple of the sink's tile rows (ts_tile_sink_open). */
  int (*put)(ts_tile_sink *s, int x, int y, int w, int h, const uint8_t *rgb, char *err);
  /* The file complete under its name; frees s, on failure too. */
  int (*finish)(ts_tile_sink *s, char *err);
  /* Nothing left under the name; frees s. */
  void (*abort)(ts_tile_sink *s);
};

/* A raster file read by regions through the image library (any format
 * ts_image_read takes, strips or tiles). meta (may be NULL): the file's
 * metadata for the output to pass on (a GeoTIFF's georeferencing); the
 * caller frees it with ts_meta_free. No pixel limit applies: the scene's
 * limit is the disk. */
int ts_region_source_open(const char *path, ts_meta **meta, ts_region_source **out, char *err);

/* A w x h RGB file written by bands through the image library: TIFF and
 * OpenEXR tiled (tile x tile, a multiple of 16) and compressed, BigTIFF
 * when large; PNG and JPEG by scanlines. meta_from: metadata to pass on
 * (may be NULL). */
int ts_tile_sink_open(const char *path, int w, int h, int tile, const ts_meta *meta_from, ts_tile_sink **out,
                      char *err);

#endif
