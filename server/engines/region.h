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

#include "gis.h"
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
  /* Where the raster lies on the earth and in which CRS, when it was read
   * through GDAL and has either; else NULL. */
  const ts_gis_georef *geo;
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

/* A raster file read by regions: a .tif or .tiff through GDAL (its
 * georeferencing in ->geo), falling back to the image library for a TIFF
 * GDAL refuses (several bands, floating point) or without GDAL; any other
 * format through the image library (region_gis.c says why). meta (may be
 * NULL): the file's metadata as the image library reads it, for an output
 * it writes (NULL if it cannot read the file); the caller frees it with
 * ts_meta_free. No pixel limit applies: the scene's limit is the disk. */
int ts_region_source_open(const char *path, ts_meta **meta, ts_region_source **out, char *err);
/* The same through the image library only (any format ts_image_read
 * takes, strips or tiles). */
int ts_region_source_open_image(const char *path, ts_meta **meta, ts_region_source **out, char *err);

/* A w x h RGB file written by bands, tile x tile blocks (a multiple of
 * 16): a .tif or .tiff through GDAL (a tiled DEFLATE GeoTIFF, BigTIFF
 * when large, georeferenced like `from` when it has ->geo; a Cloud-
 * Optimised GeoTIFF with overviews if cog); else through the image
 * library (OpenEXR tiled, PNG and JPEG by scanlines, with meta_from's
 * metadata). cog on another extension: TS_EINVAL. Without GDAL, a TIFF
 * that is no COG is written by the image library. from and meta_from may
 * be NULL. */
int ts_tile_sink_open(const char *path, int w, int h, int tile, const ts_region_source *from, const ts_meta *meta_from,
                      int cog, ts_tile_sink **out, char *err);
/* The same through the image library only: TIFF and OpenEXR tiled and
 * compressed, BigTIFF when large; PNG and JPEG by scanlines. */
int ts_tile_sink_open_image(const char *path, int w, int h, int tile, const ts_meta *meta_from, ts_tile_sink **out,
                            char *err);

/* A vector layer's lines rasterised by regions (gis.h's ts_gis_lines) at
 * the grid of `scene` (its size, and its ->geo: NULL for map coordinates
 * that are pixel coordinates): each pixel's line value, 0 for none. The
 * layer is reprojected into the scene's CRS; ts_gis_lines_open says when
 * it is refused. rules are read at the opening only. */
int ts_region_source_open_lines(const char *path, const ts_region_source *scene, const ts_gis_line_rules *rules,
                                ts_region_source **out, char *err);

/* 1 if path names a TIFF (.tif, .tiff, any case). */
int ts_region_is_tiff(const char *path);

#endif
