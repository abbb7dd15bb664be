/* tiff_tags.h - the GeoTIFF tags of a TIFF's first directory, read and
 * written as raw values. OpenImageIO neither reads nor writes them; the
 * image shim (image_oiio.cpp) turns them into metadata and back.
 *
 * The georeferencing of a GeoTIFF lives in six private TIFF tags (plus two
 * GDAL ones for metadata and nodata). They are kept verbatim, never
 * decoding the GeoKey directory: passing the raw tags on is what keeps
 * every key, known to us or not, intact. Both byte orders and BigTIFF are
 * handled. */
#ifndef TS_TIFF_TAGS_H
#define TS_TIFF_TAGS_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

#ifdef __cplusplus
extern "C" {
#endif

enum { TS_TIFF_ASCII = 2, TS_TIFF_SHORT = 3, TS_TIFF_DOUBLE = 12 };

typedef struct {
  uint16_t tag, type; /* TIFF tag number and value type (TS_TIFF_*) */
  const char *name;   /* the metadata attribute it becomes */
} ts_geotag;

#define TS_GEOTAG_COUNT 8
extern const ts_geotag ts_geotags[TS_GEOTAG_COUNT];

/* The GeoTIFF tag an attribute name stands for (case-insensitive), or
 * NULL. */
const ts_geotag *ts_geotag_named(const char *name);

/* One tag's values in host byte order: for TS_TIFF_ASCII count bytes as
 * the file holds them (NUL-terminated, as TIFF wants), for TS_TIFF_SHORT
 * count uint16_t, for TS_TIFF_DOUBLE count doubles. values NULL: the tag
 * is absent. */
typedef struct {
  size_t count;
  const void *values;
} ts_geo_value;

/* Reads the GeoTIFF tags of the first directory of the TIFF in f (a file,
 * or fmemopen'ed bytes) into tags[i], one per ts_geotags[i]; the values
 * are malloc'd, freed by ts_geo_free. A malformed tag is left out, and a
 * file that is not a TIFF has none: neither is an error, the pixels are
 * still good. 0, or TS_ENOMEM (with no tags). */
int ts_geo_read(FILE *f, ts_geo_value tags[TS_GEOTAG_COUNT]);
void ts_geo_free(ts_geo_value tags[TS_GEOTAG_COUNT]);

/* Writes tags[i] (one per ts_geotags[i]; absent ones are not written) into
 * the TIFF at path, replacing any GeoTIFF tags it has. Appends the values
 * and a copy of the first directory with these entries to the end of the
 * file, then points the header at the new directory: nothing already
 * written moves, so every offset in the old entries stays valid (the old
 * directory, a few hundred bytes, becomes unreferenced). Empty tags and
 * tags of more values than a sane TIFF holds are left out. 0, or TS_EIO,
 * TS_EFORMAT, TS_ETOOBIG or TS_ENOMEM with the reason in why (TS_ERR_LEN
 * bytes, without the file name). */
int ts_geo_write(const char *path, const ts_geo_value tags[TS_GEOTAG_COUNT], char *why);

#ifdef __cplusplus
}
#endif

#endif
