/* aerial_engine.c - synthetic aerial images from a land-use class map
 * (Stahlhut 2004, seed 002 §5.1) as an engine (engine.h): `texsyn aerial`.
 *
 * Inputs: the class map (a raster whose pixel values are class ids), one
 * reference texture per class, and optionally a line raster. As the seed
 * does (§5.1.3), lines - roads, paths, rivers: the line raster's pixels
 * whose value has a colour - are drawn first, in that colour; then the
 * classes are filled by constrained synthesis (fill.h), stochastic classes
 * first, structured ones after, each from its own reference with its own
 * usage penalty, against the three-state mask (its own area to fill, lines
 * and the classes before it known, the later classes unknown). Colour is
 * gathered from the references through the copy map (§3.8); the output is
 * 8-bit RGB, written with the class map's metadata (a GeoTIFF's
 * georeferencing stays).
 *
 * Scenes of any size: the scene is cut into tiles synthesised in phases,
 * each joined to its finished neighbours through a halo (tile_grid.h,
 * aerial_tiles.c); the class map and the lines are read by regions and the
 * image streamed to its file band by band (region.h), so memory follows the
 * tiles in flight, not the scene. A scene no larger than a tile is one
 * tile. Each finished tile is saved as a checkpoint piece (aerial_piece.c):
 * a restarted coordinator makes only the tiles not saved, with the same
 * bytes. This file: the parameters, the spec, the checks and the report. */
#include <math.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "aerial.h"
#include "error.h"
#include "image_meta.h"
#include "json.h"
#include "region.h"
#include "tile_grid.h"
#include "util.h"

_Static_assert(sizeof(aerial_job) <= TS_ENGINE_PARAMS_MAX, "aerial parameters outgrew ts_engine_params");
_Static_assert(AERIAL_MAX_CLASSES <= TS_FILL_MAX_CLASSES, "aerial classes outgrew the fill's");

enum { OUT_IMAGE = AERIAL_OUT_IMAGE, OUT_REPORT = AERIAL_OUT_REPORT, OUT_COUNT = AERIAL_OUT_COUNT };

/* The image is streamed, band by band, while the run goes. */
static const ts_engine_output aerial_outputs[OUT_COUNT] = {
    [OUT_IMAGE] = {"output", "out", TS_OUTPUT_IMAGE, .streamed = 1},
    [OUT_REPORT] = {"report", "report.json", TS_OUTPUT_FLAG},
};

#define F(field) offsetof(aerial_job, field)

/* In the spec's order; the classes' and colours' lines (classK, colourK)
 * come from the catalogue, after them. */
static const ts_param aerial_param_table[] = {
    TS_FILL_PARAMS(F(fill), "3", "7", "2"),
    {"tile", "tile", "N", TS_PARAM_INT, F(tile), 16, TS_TILE_MAX, "512",
     "side of the tiles the scene is cut into, a fixed grid: a multiple of 16 and of 2^(levels-1); the last "
     "column and row take the rest (merged into the one before when under half a tile); a scene no larger is "
     "one tile. Memory follows it: three rows of tiles are alive at once"},
    {"halo", "halo", "N", TS_PARAM_INT, F(halo), 0, TS_TILE_MAX / 2, "0",
     "finished pixels around a tile that its synthesis joins, at most half a tile; 0: the default, the coarsest "
     "neighbourhood's reach (wn/2 + 1) * 2^(levels-1) raised to a multiple of 2^(levels-1) one short of a "
     "multiple of --wb, so a block straddles each border",
     .def_help = "20 for the other defaults"},
    {"tile_jobs", "tile-jobs", "N", TS_PARAM_INT, F(tile_jobs), 0, 256, "0",
     "tiles of one phase synthesised side by side on the coordinator; never changes a pixel",
     .def_help = "the coordinator's cores"},
    {"max_pixels", NULL, NULL, TS_PARAM_U64, F(max_pixels), 0, 0, "268435456",
     "size limit of a tile's synthesis area (the scene's limit is the disk)", .flags = TS_PARAM_UNBOUNDED},
    {"cog", "cog", NULL, TS_PARAM_FLAG, F(cog), 0, 1, "0",
     "write OUT, a .tif, as a Cloud-Optimised GeoTIFF (GDAL's COG driver, as gdal_translate -of COG): "
     "DEFLATE tiles and averaged overviews halving down to one tile, georeferenced like MAP"},
    {"classes", NULL, NULL, TS_PARAM_INT, F(nclass), 1, AERIAL_MAX_CLASSES, NULL, "classes of the catalogue"},
    {"lines", NULL, NULL, TS_PARAM_FLAG, F(lines), 0, 1, "0", "a line raster is an input"},
    {"vector", NULL, NULL, TS_PARAM_FLAG, F(vector), 0, 1, "0",
     "the lines are a vector layer, drawn by the rules of the catalogue (an input too)"},
    {"colours", NULL, NULL, TS_PARAM_INT, F(ncolours), 0, AERIAL_MAX_COLOURS, "0", "colours of the line raster"},
    {NULL}};

static void aerial_params_default(void *params) {
  memset(params, 0, sizeof(aerial_job));
  ts_params_default(aerial_param_table, params);
}

/* ---- spec keys ------------------------------------------------------------
 *
 * classes=N, then classK=ID KIND USAGE_WEIGHT NAME for K = 1..N (the
 * catalogue's order; the name is the rest of the line), lines=0|1,
 * colours=M and colourK=VALUE R G B, and the fill's keys. */

static int class_set(aerial_job *p, int k, const char *v) {
  if (k < 1 || k > AERIAL_MAX_CLASSES) return TS_EINVAL;
  aerial_class *c = &p->cls[k - 1];
  char kind[16];
  int used = 0;
  if (sscanf(v, "%d %15s %lf %n", &c->id, kind, &c->usage_weight, &used) != 3 || used == 0) return TS_EINVAL;
  if (strcmp(kind, "stochastic") == 0) c->kind = AERIAL_STOCHASTIC;
  else if (strcmp(kind, "structured") == 0) c->kind = AERIAL_STRUCTURED;
  else return TS_EINVAL;
  if (c->id < 0 || c->id > AERIAL_MAX_ID || strlen(v + used) == 0 || strlen(v + used) >= AERIAL_NAME_LEN)
    return TS_EINVAL;
  snprintf(c->name, sizeof(c->name), "%s", v + used);
  return 0;
}

static int colour_set(aerial_job *p, int k, const char *v) {
  if (k < 1 || k > AERIAL_MAX_COLOURS) return TS_EINVAL;
  aerial_colour *c = &p->colour[k - 1];
  int rgb[3], used = 0;
  if (sscanf(v, "%d %d %d %d%n", &c->value, &rgb[0], &rgb[1], &rgb[2], &used) != 4 || v[used] != '\0') return TS_EINVAL;
  if (c->value < 0 || c->value > AERIAL_MAX_ID) return TS_EINVAL;
  for (int i = 0; i < 3; i++) {
    if (rgb[i] < 0 || rgb[i] > 255) return TS_EINVAL;
    c->rgb[i] = (uint8_t)rgb[i];
  }
  return 0;
}

/* The number after a key's stem ("class12" -> 12), or -1. */
static int numbered(const char *k, const char *stem) {
  size_t n = strlen(stem);
  int v;
  if (strncmp(k, stem, n) != 0 || k[n] < '1' || k[n] > '9' || ts_parse_int(k + n, 1, 100000, &v) != 0) return -1;
  return v;
}

static int aerial_spec_set(void *params, const char *k, const char *v) {
  aerial_job *p = params;
  int n, rc = ts_params_set(aerial_param_table, params, k, v);
  if (rc != TS_ENOENT) return rc;
  if ((n = numbered(k, "class")) > 0) return class_set(p, n, v);
  if ((n = numbered(k, "colour")) > 0) return colour_set(p, n, v);
  return TS_ENOENT;
}

static int aerial_spec_complete(const void *params, char *err) {
  const aerial_job *p = params;
  if (p->nclass < 1) return ts_error(err, TS_EINVAL, "job spec: classes=N (1..%d) is required", AERIAL_MAX_CLASSES);
  for (int k = 0; k < p->nclass; k++)
    if (p->cls[k].name[0] == '\0') return ts_error(err, TS_EINVAL, "job spec: class%d is missing", k + 1);
  if (p->lines && p->ncolours < 1) return ts_error(err, TS_EINVAL, "job spec: lines=1 needs colours=M and colour1..M");
  if (p->vector && !p->lines) return ts_error(err, TS_EINVAL, "job spec: vector=1 needs lines=1");
  if (p->vector && p->nclass > AERIAL_MAX_CLASSES - 1)
    return ts_error(err, TS_EINVAL, "job spec: with a vector layer, at most %d classes", AERIAL_MAX_CLASSES - 1);
  return 0;
}

static int aerial_spec_format(const void *params, char *buf, size_t cap) {
  const aerial_job *p = params;
  int n = ts_params_format(aerial_param_table, params, buf, cap);
  for (int k = 0; n >= 0 && (size_t)n < cap && k < p->nclass; k++) {
    const aerial_class *c = &p->cls[k];
    n += snprintf(buf + n, cap - (size_t)n, "class%d=%d %s %.17g %s\n", k + 1, c->id,
                  c->kind == AERIAL_STRUCTURED ? "structured" : "stochastic", c->usage_weight, c->name);
  }
  for (int k = 0; n >= 0 && (size_t)n < cap && k < p->ncolours; k++) {
    const aerial_colour *c = &p->colour[k];
    n += snprintf(buf + n, cap - (size_t)n, "colour%d=%d %d %d %d\n", k + 1, c->value, c->rgb[0], c->rgb[1], c->rgb[2]);
  }
  return n < 0 || (size_t)n >= cap ? TS_ETOOBIG : n;
}

/* The class map, the references in the catalogue's order, the lines. */
static void aerial_inputs(const void *params, ts_engine_inputs *out) {
  const aerial_job *p = params;
  out->n = 0;
  snprintf(out->name[out->n++], TS_ENGINE_KEY_LEN, "classes");
  for (int k = 0; k < p->nclass && k < AERIAL_MAX_CLASSES; k++)
    snprintf(out->name[out->n++], TS_ENGINE_KEY_LEN, "ref%d", k + 1);
  if (p->lines) snprintf(out->name[out->n++], TS_ENGINE_KEY_LEN, "lines");
  if (p->lines && p->vector) snprintf(out->name[out->n++], TS_ENGINE_KEY_LEN, "line_rules");
}

int ts_aerial_by_regions(const void *params, int k) {
  const aerial_job *p = params;
  return k == 0 || (p->lines && !p->vector && k == ts_aerial_lines_input(p));
}

/* The vector layer and the catalogue its rules are in: no images. */
static int aerial_is_file(const void *params, int k) {
  const aerial_job *p = params;
  return p->lines && p->vector && (k == ts_aerial_lines_input(p) || k == ts_aerial_rules_input(p));
}

/* ---- sources ------------------------------------------------------------------- */

/* The rules of the catalogue at path: its "lines" object, read as gis.h's
 * JSON form beside the keys the client read itself. */
static int read_rules(const char *path, ts_gis_line_rules **out, char *err) {
  static const char *const mine[] = {"vector", "colours", NULL};
  uint8_t *text;
  size_t len;
  ts_json_doc doc;
  int rc = ts_file_read(path, 1 << 20, &text, &len, err);
  if (rc != 0) return rc;
  rc = ts_json_parse(&doc, path, (const char *)text, len, 16384, err);
  free(text);
  if (rc != 0) return rc;
  int lines = doc.nodes[0].type == TS_JSON_OBJECT ? ts_json_member(&doc, 0, "lines") : -1;
  if (lines < 0) rc = ts_error(err, TS_EFORMAT, "%s: no \"lines\" object to read the line rules from", path);
  else if ((*out = malloc(sizeof(**out))) == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory");
  else rc = ts_gis_line_rules_read(&doc, lines, mine, *out, err);
  ts_json_free(&doc);
  return rc;
}

int ts_aerial_open_sources(const aerial_job *p, const ts_image *const *in, ts_meta **meta, ts_region_source **map,
                           ts_region_source **lines, ts_gis_line_rules **rules, char *err) {
  *map = *lines = NULL;
  *rules = NULL;
  const char *lines_path = p->lines ? ts_engine_file_of(in[ts_aerial_lines_input(p)])->path : NULL;
  int rc = ts_region_source_open(ts_engine_file_of(in[0])->path, meta, map, err);
  if (rc == 0 && p->vector) rc = read_rules(ts_engine_file_of(in[ts_aerial_rules_input(p)])->path, rules, err);
  if (rc == 0 && p->vector) rc = ts_region_source_open_lines(lines_path, *map, *rules, lines, err);
  else if (rc == 0 && p->lines) rc = ts_region_source_open(lines_path, NULL, lines, err);
  if (rc == 0) return 0;
  if (*map != NULL) (*map)->close(*map);
  if (meta != NULL) ts_meta_free(*meta), *meta = NULL;
  free(*rules);
  *map = NULL, *rules = NULL;
  return rc;
}

/* Chunks of ts_gis_lines_hide's 16- and 8-bit rows. */
#define HIDE_CHUNK 4096

void ts_aerial_lines_hide(const ts_gis_line_rules *rules, const int32_t *ids, int32_t *values, size_t n) {
  int any = 0;
  for (int k = 0; k < rules->nrule; k++) any |= rules->rule[k].nhidden > 0;
  if (!any) return;
  uint16_t id[HIDE_CHUNK];
  uint8_t v[HIDE_CHUNK];
  for (size_t o = 0; o < n; o += HIDE_CHUNK) {
    size_t m = n - o < HIDE_CHUNK ? n - o : HIDE_CHUNK;
    for (size_t i = 0; i < m; i++) {
      /* An id out of range is refused later, line or not. */
      id[i] = ids[o + i] >= 0 && ids[o + i] <= AERIAL_MAX_ID ? (uint16_t)ids[o + i] : 0;
      v[i] = values[o + i] > 0 && values[o + i] <= 255 ? (uint8_t)values[o + i] : 0;
    }
    ts_gis_lines_hide(rules, id, v, m);
    for (size_t i = 0; i < m; i++)
      if (v[i] == 0 && values[o + i] > 0 && values[o + i] <= 255) values[o + i] = 0;
  }
}

/* ---- the catalogue ---------------------------------------------------------- */

int ts_aerial_colour_of(const aerial_job *p, int v) {
  for (int k = 0; k < p->ncolours; k++)
    if (p->colour[k].value == v) return k;
  return -1;
}

int ts_aerial_class_of(const aerial_job *p, int id) {
  for (int k = 0; k < p->nclass; k++)
    if (p->cls[k].id == id) return k;
  return -1;
}

void ts_aerial_fill_order(const aerial_job *p, int *order) {
  int n = 0;
  for (int kind = AERIAL_STOCHASTIC; kind <= AERIAL_STRUCTURED; kind++)
    for (int k = 0; k < p->nclass; k++)
      if (p->cls[k].kind == kind) order[n++] = k;
}

int ts_aerial_halo(const aerial_job *p) {
  return p->halo > 0 ? p->halo : ts_tile_default_halo(p->fill.levels, p->fill.wn, p->fill.wb);
}

/* ---- checks ---------------------------------------------------------------- */

/* Rows read at a time by the checks. */
#define CHECK_ROWS 64

/* Class ids in the map without a catalogue entry, named with their pixel
 * counts (lines cover pixels of any class), read by regions. */
static int count_missing(const aerial_job *p, ts_region_source *map, ts_region_source *lines,
                         const ts_gis_line_rules *rules, uint64_t *count, char *err) {
  size_t w = (size_t)map->width;
  int32_t *ids = malloc(sizeof(int32_t) * w * CHECK_ROWS), *ln = lines ? malloc(sizeof(int32_t) * w * CHECK_ROWS) : NULL;
  int rc = ids == NULL || (lines != NULL && ln == NULL) ? ts_error(err, TS_ENOMEM, "out of memory") : 0;
  for (int y = 0; rc == 0 && y < map->height; y += CHECK_ROWS) {
    int h = map->height - y < CHECK_ROWS ? map->height - y : CHECK_ROWS;
    rc = map->read(map, 0, y, map->width, h, ids, err);
    if (rc == 0 && lines != NULL) rc = lines->read(lines, 0, y, lines->width, h, ln, err);
    if (rc == 0 && rules != NULL) ts_aerial_lines_hide(rules, ids, ln, w * (size_t)h);
    for (size_t i = 0; rc == 0 && i < w * (size_t)h; i++) {
      if (ln != NULL && ts_aerial_colour_of(p, ln[i]) >= 0) continue;
      if (ids[i] < 0 || ts_aerial_class_of(p, ids[i]) < 0) count[ids[i] < 0 ? AERIAL_MAX_ID + 1 : ids[i]]++;
    }
  }
  free(ids);
  free(ln);
  return rc;
}

static void check_ids(const aerial_job *p, ts_region_source *map, ts_region_source *lines,
                      const ts_gis_line_rules *rules, char *msg, size_t len, int *n) {
  char err[TS_ERR_LEN];
  uint64_t *count = calloc(AERIAL_MAX_ID + 2, sizeof(uint64_t));
  if (count == NULL || count_missing(p, map, lines, rules, count, err) != 0) {
    ts_problem(msg, len, n, "%s", count == NULL ? "out of memory" : err);
    free(count);
    return;
  }
  char list[512] = "";
  size_t used = 0;
  int missing = 0;
  for (int v = 0; v <= AERIAL_MAX_ID + 1; v++) {
    if (count[v] == 0) continue;
    if (missing++ < 12 && used < sizeof(list))
      used += (size_t)snprintf(list + used, sizeof(list) - used, "%s%s%d (%llu pixels)", missing > 1 ? ", " : "",
                               v > AERIAL_MAX_ID ? "not a whole number " : "", v > AERIAL_MAX_ID ? -1 : v,
                               (unsigned long long)count[v]);
  }
  if (missing > 0)
    ts_problem(msg, len, n, "--classes holds class ids the catalogue has no entry for: %s%s; add them to the "
               "catalogue's \"classes\"", list, missing > 12 ? ", ..." : "");
  free(count);
}

/* The grid's own problems: alignment with the pyramid, the halo, the
 * pixel limit on a tile's area. */
static void check_grid(const aerial_job *p, const ts_tile_grid *g, char *msg, size_t len, int *n) {
  int unit = 1 << (p->fill.levels - 1), halo = ts_aerial_halo(p);
  if (p->tile % 16 != 0 || p->tile % unit != 0)
    ts_problem(msg, len, n, "--tile %d: need a multiple of 16 and of 2^(levels-1) = %d, e.g. %d", p->tile, unit,
               (p->tile + (unit > 16 ? unit : 16) - 1) / (unit > 16 ? unit : 16) * (unit > 16 ? unit : 16));
  if (2 * halo > p->tile)
    ts_problem(msg, len, n, "--halo %d: at most half a tile (--tile %d); give a larger --tile or a smaller --halo%s",
               halo, p->tile, p->halo == 0 ? " (the default follows --levels and --wn)" : "");
  /* The largest area: a merged tile (under 1.5 tiles) with halos. */
  uint64_t side = (uint64_t)p->tile + (uint64_t)p->tile / 2 + 2 * (uint64_t)halo;
  uint64_t aw = side < (uint64_t)g->w ? side : (uint64_t)g->w, ah = side < (uint64_t)g->h ? side : (uint64_t)g->h;
  if (aw * ah > p->max_pixels)
    ts_problem(msg, len, n, "--tile %d: a tile's area of up to %llux%llu pixels exceeds the limit of %llu (raise "
               "--max-pixels or use a smaller --tile)", p->tile, (unsigned long long)aw, (unsigned long long)ah,
               (unsigned long long)p->max_pixels);
}

/* The smallest tile of the grid (its last column and row may be). */
static void smallest_tile(const ts_tile_grid *g, int *w, int *h) {
  int x0, x1, y0, y1;
  ts_tile_span(g->w, g->tile, g->nx, g->nx - 1, &x0, &x1);
  ts_tile_span(g->h, g->tile, g->ny, g->ny - 1, &y0, &y1);
  *w = x1 - x0 < g->tile ? x1 - x0 : g->tile;
  *h = y1 - y0 < g->tile ? y1 - y0 : g->tile;
}

/* The fill's checks of the parameters and the references, on a work area
 * of the smallest tile's size: each tile is one fill. */
static void check_fill(const aerial_job *p, const ts_image *const *in, const ts_tile_grid *g, char *msg, size_t len,
                       int *n) {
  int w, h, order[TS_FILL_MAX_CLASSES];
  smallest_tile(g, &w, &h);
  ts_aerial_fill_order(p, order);
  uint8_t *state = malloc((size_t)w * (size_t)h), *zero = calloc((size_t)w * (size_t)h, 1);
  ts_fill_class cls[TS_FILL_MAX_CLASSES];
  const char *names[TS_FILL_MAX_CLASSES];
  uint8_t *luma[TS_FILL_MAX_CLASSES] = {0};
  int ok = state != NULL && zero != NULL;
  for (int c = 0; ok && c < p->nclass; c++) {
    const ts_image *ref = in[1 + order[c]];
    ok = (luma[c] = malloc((size_t)ref->width * (size_t)ref->height)) != NULL;
    if (!ok) break;
    ts_image_luma8(ref, luma[c]);
    cls[c] = (ts_fill_class){1, {{.w = ref->width, .h = ref->height, .planes = {luma[c]}}}, p->cls[order[c]].usage_weight};
    names[c] = p->cls[order[c]].name;
  }
  if (ok) {
    memset(state, 1, (size_t)w * (size_t)h);
    ts_fill_input fi = {.w = w, .h = h, .nplanes = 1, .planes = {zero}, .state = state, .nclass = p->nclass,
                        .cls = cls, .names = names};
    char part[2048];
    if (ts_fill_check(&p->fill, &fi, names, part, sizeof(part)) != 0) ts_problem(msg, len, n, "%s", part);
  } else {
    ts_problem(msg, len, n, "out of memory");
  }
  for (int c = 0; c < p->nclass; c++) free(luma[c]);
  free(state);
  free(zero);
}

static int aerial_check(const void *params, const ts_image *const *in, char *msg, size_t len) {
  const aerial_job *p = params;
  const ts_image *map = in[0], *lines = p->lines && !p->vector ? in[ts_aerial_lines_input(p)] : NULL;
  int n = 0;
  msg[0] = '\0';
  ts_fill_check_params(&p->fill, msg, len, &n);
  ts_tile_grid g;
  if (ts_tile_grid_init(&g, map->width, map->height, p->tile, ts_aerial_halo(p)) != 0)
    ts_problem(msg, len, &n, "--classes: an empty class map");
  else if (n == 0) check_grid(p, &g, msg, len, &n);
  if (lines != NULL && (lines->width != map->width || lines->height != map->height))
    ts_problem(msg, len, &n, "the line raster is %dx%d, the class map %dx%d: they must be the same size", lines->width,
               lines->height, map->width, map->height);
  for (int k = 0; k < p->nclass; k++)
    for (int j = 0; j < k; j++)
      if (p->cls[j].id == p->cls[k].id) ts_problem(msg, len, &n, "class id %d is given twice", p->cls[k].id);
  if (n == 0) check_fill(p, in, &g, msg, len, &n);
  if (n > 0) return TS_EINVAL;
  /* The vector layer's CRS and extent are checked at its opening. */
  ts_region_source *ms = NULL, *ls = NULL;
  ts_gis_line_rules *rules = NULL;
  char err[TS_ERR_LEN];
  if (ts_aerial_open_sources(p, in, NULL, &ms, &ls, &rules, err) != 0) {
    ts_problem(msg, len, &n, "%s", err);
    return TS_EINVAL;
  }
  check_ids(p, ms, ls, rules, msg, len, &n);
  ms->close(ms);
  if (ls != NULL) ls->close(ls);
  free(rules);
  return n > 0 ? TS_EINVAL : 0;
}

static void aerial_set_max_pixels(void *params, uint64_t max_pixels) { ((aerial_job *)params)->max_pixels = max_pixels; }

/* 8-bit RGB, and on a coordinator the finished tiles' checkpoint pieces
 * (their luminance and colour, kept until the job ends): 7 bytes a pixel,
 * and a piece's header per tile. */
static uint64_t aerial_result_bytes(const void *params, const ts_engine_wants *w, const ts_image_info *in) {
  const aerial_job *p = params;
  (void)w;
  uint64_t px = (uint64_t)in[0].width * (uint64_t)in[0].height;
  uint64_t tiles = ((uint64_t)in[0].width / (uint64_t)p->tile + 1) * ((uint64_t)in[0].height / (uint64_t)p->tile + 1);
  return px * 7 + tiles * 4096 + 4096;
}

static int aerial_levels(const void *params) { return ((const aerial_job *)params)->fill.levels; }

/* ---- running ----------------------------------------------------------------- */

struct ts_engine_run {
  const aerial_job *p;
  const ts_search *search;
  int order[TS_FILL_MAX_CLASSES];
  aerial_stats st;
};

static int aerial_run(const void *params, const ts_image *const *in, ts_search *search, const ts_engine_hooks *h,
                      ts_engine_run **out, char *err) {
  ts_engine_run *r = calloc(1, sizeof(*r));
  *out = r;
  if (r == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  r->p = params;
  r->search = search;
  ts_aerial_fill_order(r->p, r->order);
  return ts_aerial_run_tiles(r->p, in, search, h, &r->st, err);
}

static int write_report(const ts_engine_run *r, const char *path, int threads, char *err) {
  char tmp[TS_FILE_TMP_LEN];
  FILE *f = ts_file_create(path, tmp, err);
  if (f == NULL) return TS_EIO;
  const aerial_job *p = r->p;
  const aerial_stats *st = &r->st;
  fprintf(f, "{\n  \"engine\": \"aerial\",\n  \"search\": {\"mode\": \"exact\", \"lossy\": [], \"backend\": \"%s\", "
             "\"simd\": \"%s\", \"threads\": %d},\n  \"params\": {",
          r->search->ops->name, r->search->simd->name, threads);
  ts_fill_report_params(f, &p->fill);
  fprintf(f, "},\n  \"tiles\": {\"tile\": %d, \"halo\": %d, \"grid\": [%d, %d], \"filled\": %llu, \"resumed\": %llu, "
             "\"tile_jobs\": %d},\n",
          p->tile, st->halo, st->nx, st->ny, (unsigned long long)st->tiles_filled,
          (unsigned long long)st->tiles_resumed, st->tile_jobs);
  fprintf(f, "  \"seconds\": %.4f,\n  \"classes\": [\n", st->seconds);
  for (int c = 0; c < p->nclass; c++) {
    const aerial_class *k = &p->cls[r->order[c]];
    fprintf(f, "    {\"order\": %d, \"id\": %d, \"name\": \"", c + 1, k->id);
    for (const char *q = k->name; *q; q++) fprintf(f, *q == '"' || *q == '\\' ? "\\%c" : "%c", *q);
    fprintf(f, "\", \"kind\": \"%s\", \"usage_weight\": %g, \"blocks\": %llu, \"usage_mean\": %.6f, "
               "\"usage_variance\": %.6f}%s\n",
            k->kind == AERIAL_STRUCTURED ? "structured" : "stochastic", k->usage_weight,
            (unsigned long long)st->blocks[c], st->usage_mean[c], st->usage_variance[c], c + 1 < p->nclass ? "," : "");
  }
  fprintf(f, "  ],\n");
  ts_fill_result res = {0};
  memcpy(res.level, st->level, sizeof(res.level));
  ts_fill_report_levels(f, &p->fill, &res);
  fprintf(f, "}\n");
  return ts_file_commit(f, tmp, path, 1, err);
}

static int aerial_write_output(const ts_engine_run *r, int k, const char *path, int threads, char *err) {
  switch (k) {
  case OUT_REPORT: return write_report(r, path, threads, err);
  default: return ts_error(err, TS_EINVAL, "the aerial engine writes no output %d after its run", k);
  }
}

static void aerial_run_free(ts_engine_run *r) { free(r); }

const ts_engine ts_engine_aerial = {
    .name = "aerial",
    .outputs = aerial_outputs,
    .noutputs = OUT_COUNT,
    .params = aerial_param_table,
    .params_default = aerial_params_default,
    .spec_set = aerial_spec_set,
    .spec_complete = aerial_spec_complete,
    .spec_format = aerial_spec_format,
    .inputs = aerial_inputs,
    .input_by_regions = ts_aerial_by_regions,
    .input_is_file = aerial_is_file,
    .check = aerial_check,
    .set_max_pixels = aerial_set_max_pixels,
    .result_bytes = aerial_result_bytes,
    .levels = aerial_levels,
    .run = aerial_run,
    .write_output = aerial_write_output,
    .run_free = aerial_run_free,
};
