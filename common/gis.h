/* gis.h - GIS rasters and vectors in and out, through GDAL (issue 28).
 *
 * What the tiled aerial engine needs of the GIS world, by regions so that
 * nothing holds a whole scene:
 *   - a raster read by regions: the class map, any single-band integer
 *     raster GDAL reads (GeoTIFF, COG, PNG, ...), with its georeferencing;
 *   - vector lines (roads, paths, rivers: any layer OGR opens, GeoJSON,
 *     Shapefile, GeoPackage) rasterised by region at the scene's grid, by
 *     rules saying which attribute value gives which line value, width and
 *     draw order;
 *   - an output written by regions: a tiled, DEFLATE-compressed GeoTIFF
 *     (BigTIFF when it needs it), georeferenced like the class map, finished
 *     as a Cloud-Optimised GeoTIFF with overviews on request.
 *
 * GDAL lives in libtexsyn-gis.so (common/gis/, gis_lib.h), loaded on the
 * first call by gis_load.c as the image library is (dl_lib.h): commands
 * that never touch a GIS file never load GDAL. The rules' JSON form is
 * parsed here, without GDAL (gis_rules.c).
 *
 * Every function returns 0 or a negative TS_E* code with a message in err
 * (TS_ERR_LEN bytes, may be NULL) naming the file and saying what to do.
 * One handle is safe to use from several threads (each call takes the
 * handle's lock: GDAL's datasets are not thread-safe); different handles
 * run in parallel.
 *
 * Coordinates: pixel (0, 0) is the top-left pixel; a region [x, x+w) x
 * [y, y+h) may reach outside the raster, whose pixels read as 0. */
#ifndef TS_GIS_H
#define TS_GIS_H

#include <stddef.h>
#include <stdint.h>

#include "error.h"
#include "json.h"

/* Where a raster lies on the earth. */
typedef struct {
  int has_geo;          /* the raster was georeferenced (a geotransform) */
  double transform[6];  /* GDAL geotransform: x0, dx, rot, y0, rot, dy (pixel corner -> map) */
  char crs_wkt[4096];   /* its CRS as WKT, "" if none */
} ts_gis_georef;

/* A region's pixel count limit (2^28, a 16384x16384 region): regions are
 * tiles, and a caller passing more has a bug or a hostile request. */
#define TS_GIS_MAX_REGION (1L << 28)

/* --- rasters by region (the class map) ------------------------------------ */

typedef struct ts_gis_raster ts_gis_raster;

/* Opens band 1 of any raster GDAL reads: one band only, of an integer
 * type (Byte, UInt16, Int16, UInt32, Int32, Int64, UInt64). geo may be
 * NULL. TS_ENOENT (no such file), TS_EFORMAT (not a raster GDAL reads,
 * more than one band, a floating-point or complex type). */
int ts_gis_raster_open(const char *path, ts_gis_raster **out, int *width, int *height, ts_gis_georef *geo,
                       char *err);
/* The class ids of region [x, x+w) x [y, y+h), row-major into dst (w*h):
 * 0 outside the raster and at its nodata value. TS_EINVAL (empty region,
 * or over TS_GIS_MAX_REGION), TS_ETOOBIG (a value below 0 or above 65535,
 * named with its pixel), TS_EIO (GDAL failed to read). */
int ts_gis_raster_read(ts_gis_raster *r, int x, int y, int w, int h, uint16_t *dst, char *err);
void ts_gis_raster_close(ts_gis_raster *r);

/* --- vector lines rasterised by region ------------------------------------ */

#define TS_GIS_MAX_RULES 64
#define TS_GIS_NAME_LEN 64 /* a field name or matched value, bytes + NUL */
#define TS_GIS_MAX_HIDDEN 16

typedef enum { TS_GIS_UNIT_MAP = 0, TS_GIS_UNIT_PIXEL = 1 } ts_gis_unit;

/* One kind of line: the features whose field equals match. */
typedef struct {
  char match[TS_GIS_NAME_LEN]; /* the field's value, as text ("road", "3"); "" when the rules have no field */
  uint8_t value;               /* 1..255: the line raster value (the catalogue's colour key) */
  double width;                /* full width, > 0, in unit */
  ts_gis_unit unit;            /* map units of the scene's CRS (metres for UTM) or pixels */
  int order;                   /* draw order: a higher order is burnt over a lower one */
  int nhidden;                 /* the classes the line is hidden under (paths under forest): */
  uint16_t hidden_under[TS_GIS_MAX_HIDDEN]; /* applied by ts_gis_lines_hide, not by the reads */
} ts_gis_line_rule;

/* Which rule each feature takes. With field "", every feature takes
 * rule[0] (nrule must be 1); else the rule whose match equals the field's
 * value, and features matching none are not drawn. width_field, if not
 * "", names a numeric attribute that overrides the rule's width per
 * feature (in the rule's unit) where it is set and > 0. Equal orders are
 * burnt in rule order, then in the layer's feature order. */
typedef struct {
  char layer[TS_GIS_NAME_LEN];       /* the layer's name; "" = the source's first layer */
  char field[TS_GIS_NAME_LEN];
  char width_field[TS_GIS_NAME_LEN];
  int nrule;                         /* 1..TS_GIS_MAX_RULES */
  ts_gis_line_rule rule[TS_GIS_MAX_RULES];
} ts_gis_line_rules;

/* The rules' JSON form (a catalogue's "lines" member may embed it):
 *   {"layer": "roads", "field": "kind", "width_field": "width",
 *    "rules": [{"match": "road", "value": 255, "width": 6, "unit": "map", "order": 2},
 *              {"match": "path", "value": 128, "width": 2, "unit": "px", "order": 1,
 *               "hidden_under": [1]}]}
 * layer, field, width_field optional; rules required, 1..TS_GIS_MAX_RULES;
 * match required with a field and refused without one, unique; value
 * 1..255; width a number > 0 and <= 10000; unit "map" (default) or "px";
 * order an integer -1000..1000 (default 0); hidden_under optional, up to
 * TS_GIS_MAX_HIDDEN distinct class ids 0..65535. Strict JSON (json.h); any
 * other key is an error. Parses len bytes (name for messages), touches no
 * file. 0, or TS_EFORMAT / TS_ELIMIT / TS_ENOMEM with "NAME:LINE:COL:
 * ..."; *out is then zeroed. */
int ts_gis_line_rules_parse(const char *text, size_t len, const char *name, ts_gis_line_rules *out, char *err);
/* The same from object node obj of a document already parsed (a
 * catalogue's "lines" member): caller_keys (NULL-terminated, may be NULL)
 * are keys of that object the caller reads itself ("vector", "colours"),
 * passed over here; any other unknown key is an error. */
int ts_gis_line_rules_read(const ts_json_doc *doc, int obj, const char *const *caller_keys, ts_gis_line_rules *out,
                           char *err);
/* Hides lines under classes: every pixel of lines whose value is a rule's
 * with hidden_under holding the pixel's class id (ids, the class map's
 * same region) becomes 0, so the class is synthesised over it. A value
 * shared by several rules is hidden under the union of their classes. n
 * pixels. */
void ts_gis_lines_hide(const ts_gis_line_rules *rules, const uint16_t *ids, uint8_t *lines, size_t n);

typedef struct ts_gis_lines ts_gis_lines;

/* Opens the vector layer at path for a scene of width x height pixels
 * placed by scene (NULL or has_geo 0: map coordinates are pixel
 * coordinates, x right, y down). Reads every line feature the rules take,
 * brings it into the scene's CRS and buffers it to its width; memory is
 * that of the vector data, never of the scene.
 *
 * Projections, decided here:
 *   - layer and scene in different CRSs: the layer is REPROJECTED into the
 *     scene's CRS (OCTTransform, traditional GIS axis order), as GIS tools
 *     overlay layers; refused (TS_EFORMAT, both CRSs named) only when PROJ
 *     has no transformation between them or a vertex fails to transform;
 *   - a layer without a CRS (a Shapefile without .prj) on a georeferenced
 *     scene: taken to be in the scene's CRS, since nothing else can be
 *     assumed; a wrong guess shows as a layer lying outside the scene,
 *     which is refused (TS_EFORMAT, both extents named) rather than giving
 *     an empty line raster; so is a layer with a CRS none of whose lines
 *     crosses the scene (the wrong layer, or the wrong scene);
 *   - a layer with a CRS on a scene without one: refused (TS_EFORMAT),
 *     there is nothing to place it against.
 * Also TS_ENOENT (no such file, no such layer or field), TS_EFORMAT (not a
 * vector source), TS_EINVAL (bad rules). */
int ts_gis_lines_open(const char *path, const ts_gis_georef *scene, int width, int height,
                      const ts_gis_line_rules *rules, ts_gis_lines **out, char *err);
/* The line value (the rule's value, 0 = none) of every pixel of region
 * [x, x+w) x [y, y+h), row-major into dst: a pixel is a line's when its
 * centre lies inside the buffered line (GDAL's rasterisation rule), so a
 * region reads the same pixels as the same area of the whole scene. */
int ts_gis_lines_read(ts_gis_lines *l, int x, int y, int w, int h, uint8_t *dst, char *err);
/* How many features were taken and whether the layer was reprojected (for
 * logs and tests); either may be NULL. */
void ts_gis_lines_info(const ts_gis_lines *l, int *nfeatures, int *reprojected);
void ts_gis_lines_close(ts_gis_lines *l);
/* A vector source as one file, to send as a job's input: path itself
 * when GDAL reads it from one file (GeoJSON, GeoPackage), else (a
 * Shapefile and its side files, ...) the same layers translated into the
 * GeoPackage dir/STEM.gpkg, into out (cap bytes). 0, TS_EFORMAT (not a
 * vector source), TS_EIO (the GeoPackage not written). */
int ts_gis_vector_single(const char *path, const char *dir, char *out, size_t cap, char *err);

/* --- output by regions ---------------------------------------------------- */

typedef struct ts_gis_writer ts_gis_writer;

/* Creates path as a tiled, DEFLATE-compressed (horizontal predictor)
 * GeoTIFF of width x height pixels, 8-bit, channels 1..4 interleaved
 * (3: RGB), tile x tile blocks (16..4096, a multiple of 16; pass the
 * engine's tile so each put fills whole blocks), BigTIFF when it may pass
 * 4 GiB (GDAL's BIGTIFF=IF_SAFER: from about 2 GB of uncompressed pixels),
 * georeferenced by geo (may be NULL). Tiles never put read as 0. Written to PATH.part and
 * renamed over path by finish, so path never holds half an image. cog:
 * finish as a Cloud-Optimised GeoTIFF with overviews (averaged, halving
 * down to one tile). Memory is GDAL's block cache (GDAL_CACHEMAX, set to
 * TS_GIS_CACHE_MB unless the environment sets it), not the image. */
#define TS_GIS_CACHE_MB 64
int ts_gis_writer_create(const char *path, int width, int height, int channels, int tile, const ts_gis_georef *geo,
                         int cog, ts_gis_writer **out, char *err);
/* Writes region [x, x+rw) x [y, y+rh), inside the image, from px
 * (rw*channels bytes a row, row-major). */
int ts_gis_writer_put(ts_gis_writer *w, int x, int y, int rw, int rh, const uint8_t *px, char *err);
/* Flushes, builds the overviews and the COG if asked, renames into place;
 * frees w whatever the outcome (on failure the partial files are removed). */
int ts_gis_writer_finish(ts_gis_writer *w, char *err);
/* Closes and removes the partial file(s); frees w. NULL is a no-op. */
void ts_gis_writer_abort(ts_gis_writer *w);

/* --- CRSs ------------------------------------------------------------------ */

/* A CRS given as "EPSG:32632", a PROJ string or WKT, as WKT into wkt
 * (len bytes). TS_EINVAL (not a CRS), TS_ETOOBIG (longer than len). */
int ts_gis_crs_wkt(const char *definition, char *wkt, size_t len, char *err);

/* Loads libtexsyn-gis.so now (every call above does it on first use):
 * 0 or TS_ENOTSUP with the reason and how to fix it. */
int ts_gis_lib_load(char *err);

#endif
