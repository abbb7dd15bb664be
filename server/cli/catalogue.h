/* catalogue.h - the aerial reference catalogue (seed 002 §5.1): which
 * reference texture each land-use class of a class map is synthesised
 * from, and in which colours the line raster (roads, paths, rivers) is
 * drawn. A JSON file (common/json.h reads it strictly):
 *
 *   {"classes": [
 *      {"id": 1, "name": "forest", "reference": "forest.png", "kind": "stochastic", "usage_weight": 1.0},
 *      {"id": 2, "name": "town",   "reference": "town.png",   "kind": "structured", "usage_weight": 0.2}],
 *    "lines": {"raster": "roads.png", "colours": {"255": [90, 90, 90], "128": 120}}}
 *
 * classes (required): 1..TS_CAT_MAX_CLASSES objects, in the order given:
 *   id            required, a whole number 0..65535, unique: the class's
 *                 pixel value in the class map
 *   name          required, 1..63 bytes of UTF-8 without control
 *                 characters, unique
 *   reference     required, the reference texture's path
 *   kind          optional, "stochastic" (the default: forest, grassland,
 *                 arable land, water) or "structured" (settlement,
 *                 industry); the seed synthesises stochastic classes first
 *                 and with stronger usage optimisation
 *   usage_weight  optional, a number 0..100 (as --usage-weight): the active
 *                 usage-penalty weight of the class; default 1.0 for a
 *                 stochastic class and 0.2 for a structured one (the seed:
 *                 stronger for stochastic textures, weaker for structured
 *                 ones, which it harms more)
 * lines (optional): the linear objects, drawn rather than synthesised:
 *   raster        required, the path of the line raster (same size as the
 *                 class map)
 *   colours       required, 1..TS_CAT_MAX_COLOURS members: a key is a pixel
 *                 value of the raster (0..65535 in decimal, no sign or
 *                 leading zero), its value the colour of those pixels:
 *                 [R, G, B] with 0..255 each, or one number 0..255 for a
 *                 grey. Four numbers are refused: lines are drawn opaque,
 *                 an alpha would promise blending that does not happen.
 *                 Pixels with other values are not lines.
 *
 * Paths are relative to the catalogue file's directory (absolute ones are
 * kept as they are). Any other key, a key given twice, a value of the wrong
 * type or out of range is an error naming the file, line and column (see
 * json.h), the class and what was expected. Classes are counted from 1 in
 * their order in the file ("class 2 (\"town\")"), whatever their ids. */
#ifndef TS_CATALOGUE_H
#define TS_CATALOGUE_H

#include <limits.h>
#include <stddef.h>
#include <stdint.h>

#define TS_CAT_MAX_CLASSES 64
#define TS_CAT_MAX_COLOURS 256
#define TS_CAT_NAME_LEN 64              /* name bytes + NUL */
#define TS_CAT_MAX_BYTES (1024 * 1024)  /* a catalogue file's size limit */
#define TS_CAT_MAX_ID 65535

#define TS_CAT_STOCHASTIC_WEIGHT 1.0
#define TS_CAT_STRUCTURED_WEIGHT 0.2
#define TS_CAT_MAX_WEIGHT 100.0

typedef enum { TS_CAT_STOCHASTIC = 0, TS_CAT_STRUCTURED = 1 } ts_cat_kind;

typedef struct {
  int id;
  char name[TS_CAT_NAME_LEN];
  char reference[PATH_MAX]; /* joined with the catalogue's directory */
  ts_cat_kind kind;
  double usage_weight;
  int line, col;            /* where "reference" is given, for later messages */
} ts_cat_class;

typedef struct {
  uint32_t value; /* pixel value in the line raster */
  uint8_t rgb[3];
} ts_cat_colour;

/* About 270 KB (the paths): allocate it, don't put it on a small stack. */
typedef struct {
  int nclass;
  ts_cat_class cls[TS_CAT_MAX_CLASSES]; /* in the file's order */
  int has_lines;
  int line_vector;                      /* line_raster names a vector layer ("vector") */
  char line_raster[PATH_MAX];           /* the line raster or vector layer */
  int raster_line, raster_col;          /* where "raster" or "vector" is given */
  int ncolours;
  ts_cat_colour colour[TS_CAT_MAX_COLOURS]; /* in the file's order */
} ts_catalogue;

/* Parses a catalogue's len bytes of text (name: what messages call it;
 * base_dir: the directory relative paths are joined to, "" or NULL for
 * none). Touches no file. 0, or TS_EFORMAT (not strict JSON, or not a
 * catalogue), TS_ELIMIT (nested too deep, too many values) or TS_ENOMEM,
 * with a "NAME:LINE:COL: ..." message; *out is then zeroed. */
int ts_catalogue_parse(const char *text, size_t len, const char *name, const char *base_dir,
                       ts_catalogue *out, char *err);

/* Reads the catalogue file at path (at most TS_CAT_MAX_BYTES), parses it
 * with its directory as base_dir, and checks that every reference and the
 * line raster is an existing regular file. 0, or ts_catalogue_parse's
 * errors, TS_ETOOBIG, TS_EIO (unreadable catalogue), TS_EINVAL (its path
 * too long), TS_ENOENT (a path named in it is missing or not a regular
 * file, with its line and column); *out is then zeroed. */
int ts_catalogue_load(const char *path, ts_catalogue *out, char *err);

/* "stochastic" or "structured". */
const char *ts_cat_kind_name(ts_cat_kind kind);

#endif
