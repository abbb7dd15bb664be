/* aerial_tiles.c - the aerial run, tile by tile (aerial.h).
 *
 * The scene is cut on the grid of tile_grid.h and its tiles synthesised in
 * the wavefront order there: per even tile row r, phases 0 and 1 of row r,
 * then phases 2 and 3 of row r - 1. A tile is one constrained synthesis
 * (fill.h) over its area: its own pixels to fill (lines given in their
 * colours' luminance, each class the work of its fill rank), the finished
 * halo around them given. Its seed is ts_tile_seed(job seed, tile index).
 *
 * Memory holds three tile rows, "bands", each the whole scene's width: the
 * pixel states read from the class map and the line raster by regions, top
 * to bottom, when the row is first needed, the finished pixels' luminance (what later
 * tiles' halos give) and their colours. Rows are written to the output
 * (a tile sink, region.h) top to bottom as they complete - an even row
 * completes before the odd row above it, so it waits for that one - and a
 * band is reused for the row three below once written: the even row r is
 * read by the odd rows r - 1 and r + 1, odd rows by no other row. So the
 * coordinator's memory is three bands and the tiles in flight, whatever
 * the scene's height; a band is 10 bytes a pixel of the scene's width.
 *
 * The finished pixels' copies (where in their class's reference) are kept
 * too: a later tile's fill gets its halo as copies, so its seam cut
 * (fill_seams.h) joins its work to its finished neighbours as it joins two
 * of its own blocks, and a tile border is no more a seam than a block
 * edge is. */
#include <pthread.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/statvfs.h>
#include <unistd.h>

#include "aerial.h"
#include "cursor.h"
#include "error.h"
#include "image_meta.h"
#include "jobspec.h"
#include "preview.h"
#include "region.h"
#include "tile_grid.h"
#include "util.h"

#define BANDS 3
#define READ_ROWS 64 /* rows of the class map read at a time */
#define NO_CLASS 0xFF
#define AERIAL_MAX_TILE_JOBS 256

typedef struct {
  int row; /* the tile row held; -1: none */
  int y0, h;
  uint8_t *state; /* per pixel: 0 a line, else 1 + its class's fill rank */
  uint8_t *luma;  /* finished pixels: the fill's plane; lines their colour's */
  uint8_t *rgb;   /* finished pixels' colours */
  uint32_t *src;  /* finished pixels' copies: y * width + x in their class's reference */
  size_t cap;     /* pixels the buffers hold */
  int tiles_done, written;
} band;

typedef struct {
  const aerial_job *p;
  const ts_engine_hooks *h;
  aerial_stats *st;
  ts_tile_grid g;
  int order[TS_FILL_MAX_CLASSES]; /* catalogue index of each fill rank */
  /* Per fill rank: the reference as 8-bit RGB and its luminance. */
  int rw[TS_FILL_MAX_CLASSES], rh[TS_FILL_MAX_CLASSES];
  uint8_t *ref_rgb[TS_FILL_MAX_CLASSES], *ref_luma[TS_FILL_MAX_CLASSES];
  uint8_t *rank_of_id;   /* class id -> fill rank, NO_CLASS */
  int16_t *colour_of_id; /* line value -> colour index, -1 */
  ts_region_source *map, *lines;
  ts_gis_line_rules *rules; /* a vector layer's, NULL for a line raster */
  ts_meta *meta;
  ts_tile_sink *sink;
  ts_preview *preview; /* NULL: none, or given up after a failed write */
  int32_t *ids, *values; /* READ_ROWS rows of the map and the lines */
  band bands[BANDS];
  int next_write; /* the next tile row to write */
  int row, phase; /* the step under way */
  int step_done0; /* tiles done when it began */
  /* Tiles of a step run on `jobs` threads, each with a search session of
   * its own (search.h; sessions[0] is the run's search). Under `lock`:
   * the progress, the resumed count, the first error. */
  int jobs;
  ts_search *sessions[AERIAL_MAX_TILE_JOBS];
  pthread_mutex_t lock;
  int tiles_done, resumed, told;
  double share[AERIAL_MAX_TILE_JOBS]; /* of each thread's tile under way */
} tiler;

/* ---- the job's tables and references ------------------------------------------ */

static uint8_t luma_of(const uint8_t *rgb) { return (uint8_t)((299 * rgb[0] + 587 * rgb[1] + 114 * rgb[2] + 500) / 1000); }

static int build_tables(tiler *t, const ts_image *const *in, char *err) {
  const aerial_job *p = t->p;
  t->rank_of_id = malloc(AERIAL_MAX_ID + 1);
  t->colour_of_id = malloc(sizeof(int16_t) * (AERIAL_MAX_ID + 1));
  if (t->rank_of_id == NULL || t->colour_of_id == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  memset(t->rank_of_id, NO_CLASS, AERIAL_MAX_ID + 1);
  for (int v = 0; v <= AERIAL_MAX_ID; v++) t->colour_of_id[v] = -1;
  for (int k = p->ncolours - 1; k >= 0; k--) t->colour_of_id[p->colour[k].value] = (int16_t)k;
  ts_aerial_fill_order(p, t->order);
  for (int r = 0; r < p->nclass; r++) {
    t->rank_of_id[p->cls[t->order[r]].id] = (uint8_t)r;
    const ts_image *ref = in[1 + t->order[r]];
    size_t n = (size_t)ref->width * (size_t)ref->height;
    t->rw[r] = ref->width;
    t->rh[r] = ref->height;
    t->ref_rgb[r] = malloc(3 * n);
    t->ref_luma[r] = malloc(n);
    uint8_t *plane = malloc(n);
    if (t->ref_rgb[r] == NULL || t->ref_luma[r] == NULL || plane == NULL) {
      free(plane);
      return ts_error(err, TS_ENOMEM, "out of memory");
    }
    ts_image_luma8(ref, t->ref_luma[r]);
    for (int c = 0; c < 3; c++) { /* grey references give all three */
      ts_image_channel8(ref, ref->channels >= 3 ? c : 0, plane);
      for (size_t i = 0; i < n; i++) t->ref_rgb[r][3 * i + (size_t)c] = plane[i];
    }
    free(plane);
  }
  return 0;
}

/* ---- bands -------------------------------------------------------------------- */

static band *band_of_row(tiler *t, int row) { return &t->bands[row % BANDS]; }

/* A pixel's state from the map and the lines (lines drawn at once). */
static int put_pixel(tiler *t, band *b, size_t o, int32_t id, int32_t value, int x, int y, char *err) {
  int line = t->lines != NULL && value >= 0 ? t->colour_of_id[value] : -1;
  if (line >= 0) {
    const uint8_t *rgb = t->p->colour[line].rgb;
    b->state[o] = 0;
    b->luma[o] = luma_of(rgb);
    memcpy(b->rgb + 3 * o, rgb, 3);
    return 0;
  }
  int rank = id >= 0 ? t->rank_of_id[id] : NO_CLASS;
  if (rank == NO_CLASS)
    return ts_error(err, TS_EINVAL, "--classes: pixel (%d, %d) holds class id %d, which the catalogue has no entry "
                    "for (did the file change since the job was checked?)", x, y, id);
  b->state[o] = (uint8_t)(rank + 1);
  return 0;
}

/* Reads tile row `row`'s states into its band. */
static int band_load(tiler *t, int row, char *err) {
  band *b = band_of_row(t, row);
  if (b->row == row) return 0;
  if (b->row >= 0 && !b->written)
    return ts_error(err, TS_EINVAL, "internal: tile row %d is needed while row %d is not yet written", row, b->row);
  int y1, w = t->g.w;
  ts_tile_span(t->g.h, t->g.tile, t->g.ny, row, &b->y0, &y1);
  b->h = y1 - b->y0;
  size_t npx = (size_t)w * (size_t)b->h;
  if (npx > b->cap) {
    free(b->state);
    free(b->luma);
    free(b->rgb);
    free(b->src);
    b->state = malloc(npx);
    b->luma = malloc(npx);
    b->rgb = malloc(3 * npx);
    b->src = malloc(sizeof(uint32_t) * npx);
    b->cap = b->state && b->luma && b->rgb && b->src ? npx : 0;
    if (b->cap == 0) return ts_error(err, TS_ENOMEM, "out of memory for a row of tiles (%dx%d)", w, b->h);
  }
  b->row = row;
  b->tiles_done = b->written = 0;
  for (int y = 0; y < b->h; y += READ_ROWS) {
    int n = b->h - y < READ_ROWS ? b->h - y : READ_ROWS;
    int rc = t->map->read(t->map, 0, b->y0 + y, w, n, t->ids, err);
    if (rc == 0 && t->lines != NULL) rc = t->lines->read(t->lines, 0, b->y0 + y, w, n, t->values, err);
    if (rc == 0 && t->rules != NULL) ts_aerial_lines_hide(t->rules, t->ids, t->values, (size_t)w * (size_t)n);
    for (size_t i = 0; rc == 0 && i < (size_t)w * (size_t)n; i++)
      rc = put_pixel(t, b, (size_t)y * (size_t)w + i, t->ids[i], t->lines != NULL ? t->values[i] : -1,
                     (int)(i % (size_t)w), b->y0 + y + (int)(i / (size_t)w), err);
    if (rc != 0) return rc;
  }
  return 0;
}

/* The preview is for the operations page only: one that cannot be
 * written is dropped, and the job goes on. */
static void preview_rows(tiler *t, const band *b) {
  char perr[TS_ERR_LEN];
  if (t->preview != NULL && ts_preview_rows(t->preview, b->y0, b->h, b->rgb, perr) != 0) {
    ts_preview_close(t->preview);
    t->preview = NULL;
  }
}

/* Writes every completed row whose turn it is. */
static int write_rows(tiler *t, char *err) {
  while (t->next_write < t->g.ny) {
    band *b = band_of_row(t, t->next_write), *below = band_of_row(t, t->next_write + 1);
    if (b->row != t->next_write || b->tiles_done < t->g.nx) return 0;
    /* The odd row below an even one changes its last rows (tile_store). */
    if (t->next_write % 2 == 0 && t->next_write + 1 < t->g.ny &&
        (below->row != t->next_write + 1 || below->tiles_done < t->g.nx))
      return 0;
    int rc = t->sink->put(t->sink, 0, b->y0, t->g.w, b->h, b->rgb, err);
    if (rc != 0) return rc;
    preview_rows(t, b);
    b->written = 1;
    t->next_write++;
  }
  return 0;
}

/* ---- one tile ------------------------------------------------------------------- */

/* A tile's fill: its area's planes and states, the classes present. */
typedef struct {
  ts_tile_rect core, area;
  int w, h;
  uint8_t *plane, *state;
  uint8_t *given_from; /* the halo's copies, for the seam cut (ts_fill_input) */
  uint32_t *given_copy;
  uint8_t *given_cut; /* the halo pixels next to the core, which the cut may change */
  ts_wr edits;        /* those it changed, as the piece keeps them (aerial_piece.c) */
  uint32_t nedits;
  int nclass;
  int rank[TS_FILL_MAX_CLASSES]; /* fill rank of each of its classes */
  ts_fill_class cls[TS_FILL_MAX_CLASSES];
  const char *names[TS_FILL_MAX_CLASSES];
} tile_fill;

static void tile_fill_free(tile_fill *f) {
  free(f->plane);
  free(f->state);
  free(f->given_from);
  free(f->given_copy);
  free(f->given_cut);
  ts_wr_free(&f->edits);
}

/* The band pixel (x, y) of the scene is in. */
static size_t band_pixel(tiler *t, int x, int y, band **b) {
  int row = y / t->g.tile < t->g.ny ? y / t->g.tile : t->g.ny - 1;
  *b = band_of_row(t, row);
  return (size_t)(y - (*b)->y0) * (size_t)t->g.w + (size_t)x;
}

/* Whether a pixel outside the core is one of the `reach` next to it
 * across one of its edges (not a corner): the halo pixels a tile's seam cut
 * may change, so a tile border is cut from both sides as a block edge is.
 * Only tiles of later phases than the pixel's own have it in their halo,
 * and tiles of one step change disjoint pixels that none of them reads
 * (a halo is at most half a tile, the reach a few pixels). */
static int next_to_core(const ts_tile_rect *c, int x, int y, int reach) {
  int in_x = x >= c->x0 && x < c->x1, in_y = y >= c->y0 && y < c->y1;
  return (in_y && ((x >= c->x0 - reach && x < c->x0) || (x >= c->x1 && x < c->x1 + reach))) ||
         (in_x && ((y >= c->y0 - reach && y < c->y0) || (y >= c->y1 && y < c->y1 + reach)));
}

/* The area's states: the core's from its band, its classes renumbered in
 * fill order (1..nclass); the halo given, with its finished luminance. */
static int tile_build(tiler *t, int tx, int ty, tile_fill *f) {
  memset(f, 0, sizeof(*f));
  f->core = ts_tile_core(&t->g, tx, ty);
  f->area = ts_tile_area(&t->g, tx, ty);
  f->w = f->area.x1 - f->area.x0;
  f->h = f->area.y1 - f->area.y0;
  size_t npx = (size_t)f->w * (size_t)f->h;
  f->plane = malloc(npx);
  f->state = malloc(npx);
  f->given_from = calloc(npx, 1);
  f->given_copy = calloc(2 * npx, sizeof(uint32_t));
  f->given_cut = calloc(npx, 1);
  ts_wr_init(&f->edits);
  if (f->plane == NULL || f->state == NULL || f->given_from == NULL || f->given_copy == NULL || f->given_cut == NULL)
    return TS_ENOMEM;
  int present[TS_FILL_MAX_CLASSES] = {0}, local[TS_FILL_MAX_CLASSES];
  band *b = band_of_row(t, ty);
  for (int y = f->core.y0; y < f->core.y1; y++)
    for (int x = f->core.x0; x < f->core.x1; x++) {
      int s = b->state[(size_t)(y - b->y0) * (size_t)t->g.w + (size_t)x];
      if (s > 0) present[s - 1] = 1;
    }
  for (int r = 0; r < t->p->nclass; r++) {
    if (!present[r]) continue;
    local[r] = ++f->nclass;
    f->rank[f->nclass - 1] = r;
    f->cls[f->nclass - 1] = (ts_fill_class){1, {{.w = t->rw[r], .h = t->rh[r], .planes = {t->ref_luma[r]}}},
                                            t->p->cls[t->order[r]].usage_weight};
    f->names[f->nclass - 1] = t->p->cls[t->order[r]].name;
  }
  for (int y = f->area.y0; y < f->area.y1; y++)
    for (int x = f->area.x0; x < f->area.x1; x++) {
      band *pb;
      size_t o = band_pixel(t, x, y, &pb), i = (size_t)(y - f->area.y0) * (size_t)f->w + (size_t)(x - f->area.x0);
      int core = x >= f->core.x0 && x < f->core.x1 && y >= f->core.y0 && y < f->core.y1;
      int s = core ? pb->state[o] : 0;
      f->state[i] = (uint8_t)(s > 0 ? local[s - 1] : 0);
      f->plane[i] = s > 0 ? 0 : pb->luma[o];
      int r = core ? 0 : pb->state[o]; /* a finished pixel of class rank r - 1, or a line */
      if (r > 0 && present[r - 1]) {
        f->given_from[i] = (uint8_t)local[r - 1];
        f->given_copy[2 * i] = pb->src[o] % (uint32_t)t->rw[r - 1];
        f->given_copy[2 * i + 1] = pb->src[o] / (uint32_t)t->rw[r - 1];
        f->given_cut[i] = (uint8_t)next_to_core(&f->core, x, y, t->p->fill.seam_cut);
      }
    }
  return 0;
}

/* Sums a tile's figures (a piece's) into the run's. */
static void add_stats(tiler *t, const aerial_piece *pc) {
  aerial_stats *st = t->st;
  for (int l = 0; l < t->p->fill.levels; l++) {
    ts_fill_level_stats *a = &st->level[l];
    const ts_fill_level_stats *b = &pc->level[l];
    a->seconds += b->seconds;
    a->blocks += b->blocks;
    a->steps += b->steps;
    a->seeds += b->seeds;
    a->pairs += b->pairs;
    a->wire_bytes += b->wire_bytes;
    a->round_trips += b->round_trips;
    a->w = ((t->g.w - 1) >> l) + 1;
    a->h = ((t->g.h - 1) >> l) + 1;
  }
  for (int c = 0; c < pc->nclass; c++) {
    int r = pc->rank[c];
    const ts_fill_class_stats *s = &pc->cls[c];
    uint64_t n = st->blocks[r] + s->blocks;
    if (n == 0) continue;
    double wa = (double)st->blocks[r] / (double)n, wb = (double)s->blocks / (double)n;
    st->usage_mean[r] = wa * st->usage_mean[r] + wb * s->usage_mean;
    st->usage_variance[r] = wa * st->usage_variance[r] + wb * s->usage_variance;
    st->blocks[r] = n;
  }
  if (pc->nclass > 0) st->tiles_filled++;
}

/* The tile's piece: its core in its band, and its figures. */
static void piece_of(tiler *t, int tx, int ty, const tile_fill *f, const ts_fill_result *res, aerial_piece *pc) {
  band *b = band_of_row(t, ty);
  memset(pc, 0, sizeof(*pc));
  size_t o = (size_t)(f->core.y0 - b->y0) * (size_t)t->g.w + (size_t)f->core.x0;
  *pc = (aerial_piece){.index = (uint32_t)ts_tile_index(&t->g, tx, ty), .x0 = f->core.x0, .y0 = f->core.y0,
                       .w = f->core.x1 - f->core.x0, .h = f->core.y1 - f->core.y0, .luma = b->luma + o,
                       .rgb = b->rgb + 3 * o, .src = b->src + o, .stride = (size_t)t->g.w, .nclass = f->nclass};
  if (res == NULL) return;
  memcpy(pc->rank, f->rank, sizeof(pc->rank));
  pc->nedits = f->nedits;
  pc->edits = f->edits.buf;
  memcpy(pc->cls, res->cls, sizeof(pc->cls));
  memcpy(pc->level, res->level, sizeof(pc->level));
}

/* Saves a finished tile as a checkpoint piece (hooks->save_piece). */
static int save_piece(tiler *t, const aerial_piece *pc, char *err) {
  uint8_t *buf;
  size_t len;
  char name[32];
  if (ts_aerial_piece_encode(pc, t->p->fill.levels, t->h->tag, &buf, &len) != 0)
    return ts_error(err, TS_ENOMEM, "out of memory for a tile's checkpoint");
  snprintf(name, sizeof(name), "tile-%u", pc->index);
  int rc = t->h->save_piece(t->h->save_ctx, name, buf, len, err);
  free(buf);
  return rc;
}

/* A finished pixel (x, y) of class rank r into its band: luminance for
 * later halos, colour through its copy src. */
static void store_pixel(tiler *t, int x, int y, uint8_t luma, int r, uint32_t src) {
  band *b;
  size_t o = band_pixel(t, x, y, &b);
  b->luma[o] = luma;
  b->src[o] = src;
  memcpy(b->rgb + 3 * o, t->ref_rgb[r] + 3 * (size_t)src, 3);
}

/* An edit of a halo pixel as a piece keeps it: x, y, rank, copy, luma. */
static void edit_put(ts_wr *w, int x, int y, int r, uint32_t src, uint8_t luma) {
  ts_wr_u32(w, (uint32_t)x);
  ts_wr_u32(w, (uint32_t)y);
  ts_wr_u32(w, (uint32_t)r);
  ts_wr_u32(w, src);
  ts_wr_u8(w, luma);
}

/* A resumed tile's changes to its halo, as its making made them: 0, or
 * TS_EPROTO, nothing applied, when an edit is not of a pixel next to the
 * tile's core c or names no copy of a class (the tile is made again). */
static int apply_edits(tiler *t, const ts_tile_rect *c, const aerial_piece *fig) {
  for (int pass = 0; pass < 2; pass++)
    for (uint32_t k = 0; k < fig->nedits; k++) {
      const uint8_t *e = fig->edits + (size_t)k * AERIAL_EDIT_BYTES;
      uint32_t x = (uint32_t)ts_get_le(e, 4), y = (uint32_t)ts_get_le(e + 4, 4), r = (uint32_t)ts_get_le(e + 8, 4);
      uint32_t src = (uint32_t)ts_get_le(e + 12, 4);
      if (pass == 1) store_pixel(t, (int)x, (int)y, e[16], (int)r, src);
      else if (x >= (uint32_t)t->g.w || y >= (uint32_t)t->g.h || !next_to_core(c, (int)x, (int)y, t->p->fill.seam_cut) ||
               r >= (uint32_t)t->p->nclass || src >= (uint32_t)t->rw[r] * (uint32_t)t->rh[r])
        return TS_EPROTO;
    }
  return 0;
}

/* A tile an earlier run of the job finished: 1 with its core in its band
 * and its figures in *fig, 0 if there is none that fits (it is made). */
static int load_piece(tiler *t, int tx, int ty, aerial_piece *fig) {
  uint8_t *buf = NULL;
  size_t len = 0;
  char name[32], why[TS_ERR_LEN];
  ts_tile_rect c = ts_tile_core(&t->g, tx, ty);
  uint32_t index = (uint32_t)ts_tile_index(&t->g, tx, ty);
  snprintf(name, sizeof(name), "tile-%u", index);
  if (t->h->load_piece(t->h->save_ctx, name, &buf, &len, why) != 0) return 0;
  int ok = ts_aerial_piece_decode(buf, len, t->p->fill.levels, t->h->tag, index, c.x0, c.y0, c.x1 - c.x0, c.y1 - c.y0,
                                  fig, why) == 0;
  if (ok && apply_edits(t, &c, fig) != 0) ok = 0;
  if (ok) {
    band *b = band_of_row(t, ty);
    for (int y = 0; y < fig->h; y++) {
      size_t o = (size_t)(c.y0 + y - b->y0) * (size_t)t->g.w + (size_t)c.x0;
      memcpy(b->luma + o, fig->luma + (size_t)y * (size_t)fig->w, (size_t)fig->w);
      memcpy(b->rgb + 3 * o, fig->rgb + 3 * (size_t)y * (size_t)fig->w, 3 * (size_t)fig->w);
      for (int x = 0; x < fig->w; x++)
        b->src[o + (size_t)x] = (uint32_t)ts_get_le(fig->src_le + 4 * ((size_t)y * (size_t)fig->w + (size_t)x), 4);
    }
    fig->luma = fig->rgb = fig->src_le = NULL; /* in buf, freed below */
    pthread_mutex_lock(&t->lock);
    t->resumed++;
    pthread_mutex_unlock(&t->lock);
  }
  free(buf);
  return ok;
}

/* Tells the hooks, once, that the run goes on from earlier runs' tiles. */
static void tell_resumed(tiler *t) {
  pthread_mutex_lock(&t->lock);
  if (t->resumed > 0 && !t->told && t->h->resumed != NULL) {
    char where[96];
    /* Tiles of the step under way may still be found on other threads. */
    snprintf(where, sizeof(where), "with at least %d of its %d tiles finished", t->resumed, ts_tile_count(&t->g));
    t->h->resumed(t->h->save_ctx, where, 0);
    t->told = 1;
  }
  pthread_mutex_unlock(&t->lock);
}

/* The filled core into its band, and the halo pixels the seam cut changed
 * into theirs (kept as the piece's edits). */
static int tile_store(tiler *t, tile_fill *f, const ts_fill_result *res) {
  for (int y = f->area.y0; y < f->area.y1; y++)
    for (int x = f->area.x0; x < f->area.x1; x++) {
      size_t i = (size_t)(y - f->area.y0) * (size_t)f->w + (size_t)(x - f->area.x0);
      int local = f->state[i] != 0 ? f->state[i] : res->source[i] != TS_FILL_NO_SOURCE ? f->given_from[i] : 0;
      if (local == 0) continue;
      int r = f->rank[local - 1];
      uint32_t src = res->copy[2 * i + 1] * (uint32_t)t->rw[r] + res->copy[2 * i];
      store_pixel(t, x, y, res->planes[0][i], r, src);
      if (f->state[i] != 0) continue;
      edit_put(&f->edits, x, y, r, src, res->planes[0][i]);
      f->nedits++;
    }
  return ts_wr_status(&f->edits) == 0 ? 0 : TS_ENOMEM;
}

/* One thread of a step: its session, its slot in the progress. */
typedef struct {
  tiler *t;
  int slot;
  ts_search *search;
  ts_tile_step step;
  atomic_int *next;     /* the step's next tile to take */
  aerial_piece *figs;   /* per tile of the step, its figures */
  char *err;            /* the step's first error (under t->lock) */
  int *rc;
} tile_worker;

/* Progress (under t->lock, so the hook is called by one thread at a
 * time): done and total count tiles, the work is the tiles done plus the
 * shares of those under way (the ETA's base: progress.h); the stage names
 * the tiles done when the step began and the step, "12 of 64 tiles done,
 * row 3 of 8, phase 2 of 4": a line per step in a client's log, not one
 * per tile or per class of every tile. */
static void report_progress(tiler *t) {
  if (t->h->progress == NULL) return;
  int total = ts_tile_count(&t->g);
  double work = t->tiles_done;
  for (int i = 0; i < t->jobs; i++) work += t->share[i];
  ts_progress p = {.level = 0, .levels = 1, .done = (uint64_t)t->tiles_done, .total = (uint64_t)total,
                   .work_done = work, .work_total = total};
  snprintf(p.stage, sizeof(p.stage), "%d of %d tiles done, row %d of %d, phase %d of 4", t->step_done0, total,
           t->row + 1, t->g.ny, t->phase + 1);
  t->h->progress(t->h->progress_ctx, &p);
}

static void on_fill_progress(void *ctx, const ts_progress *fp) {
  tile_worker *w = ctx;
  pthread_mutex_lock(&w->t->lock);
  w->t->share[w->slot] = fp->work_total > 0 ? fp->work_done / fp->work_total : 0;
  report_progress(w->t);
  pthread_mutex_unlock(&w->t->lock);
}

/* Synthesises a tile into its band and saves it as a piece; its figures
 * into *fig. */
static int make_tile(tile_worker *w, int tx, int ty, aerial_piece *fig, char *err) {
  tiler *t = w->t;
  tile_fill f;
  int rc = tile_build(t, tx, ty, &f);
  if (rc != 0) {
    tile_fill_free(&f);
    return ts_error(err, rc, "out of memory for tile (%d, %d)", tx, ty);
  }
  if (f.nclass > 0) {
    ts_fill_params fp = t->p->fill;
    fp.seed = ts_tile_seed(t->p->fill.seed, (uint32_t)ts_tile_index(&t->g, tx, ty));
    ts_fill_input in = {.w = f.w, .h = f.h, .nplanes = 1, .planes = {f.plane}, .state = f.state,
                        .nclass = f.nclass, .cls = f.cls, .names = f.names, .given_from = f.given_from,
                        .given_copy = f.given_copy, .given_cut = f.given_cut};
    ts_progress_hooks ph = {t->h->progress ? on_fill_progress : NULL, w};
    ts_fill_result res;
    rc = ts_fill_synthesize(&fp, &in, w->search, &ph, &res, err);
    if (rc == 0 && (rc = tile_store(t, &f, &res)) != 0) ts_error(err, rc, "out of memory");
    if (rc == 0) piece_of(t, tx, ty, &f, &res, fig);
    ts_fill_result_free(&res);
  } else {
    piece_of(t, tx, ty, &f, NULL, fig); /* lines only */
  }
  if (rc == 0 && t->h->save_piece != NULL) rc = save_piece(t, fig, err);
  tile_fill_free(&f);
  return rc;
}

/* A tile: from an earlier run's piece, or made. */
static int run_tile(tile_worker *w, int tx, int ty, aerial_piece *fig, char *err) {
  tiler *t = w->t;
  if (t->h->load_piece != NULL && load_piece(t, tx, ty, fig)) return 0;
  tell_resumed(t);
  return make_tile(w, tx, ty, fig, err);
}

/* A thread of a step: takes the step's tiles in turn until none is left
 * or a tile failed. Which thread makes which tile changes no pixel: a
 * tile reads only tiles of earlier steps. */
static void *step_worker(void *arg) {
  tile_worker *w = arg;
  tiler *t = w->t;
  char err[TS_ERR_LEN];
  for (;;) {
    int k = atomic_fetch_add(w->next, 1), tx = w->step.xpar + 2 * k;
    if (tx >= t->g.nx) break;
    pthread_mutex_lock(&t->lock);
    int failed = *w->rc != 0;
    pthread_mutex_unlock(&t->lock);
    if (failed) break;
    int rc = t->h->stop != NULL && atomic_load(t->h->stop) ? ts_error(err, TS_ESTOPPED, "stopped")
                                                           : run_tile(w, tx, w->step.row, &w->figs[k], err);
    pthread_mutex_lock(&t->lock);
    if (rc != 0 && *w->rc == 0) {
      *w->rc = rc;
      memcpy(w->err, err, TS_ERR_LEN);
    }
    if (rc == 0) t->tiles_done++;
    t->share[w->slot] = 0;
    report_progress(t);
    pthread_mutex_unlock(&t->lock);
  }
  return NULL;
}

/* ---- the run ------------------------------------------------------------------- */

/* ---- the run ------------------------------------------------------------------- */

/* The output file's tiles: the largest power of two from 16 to 512 that
 * divides the grid's tile, so every band is whole file tiles. */
static int file_tile(int tile) {
  int ft = 512;
  while (ft > 16 && tile % ft != 0) ft /= 2;
  return ft;
}

/* The output's room, before any tile is made: the bytes the file may take
 * at most against the free space of its file system (statvfs, blocks free
 * to unprivileged users). The bound is the uncompressed samples - 3 bytes
 * a pixel, 6 for OpenEXR (half floats) - plus 1/64 for DEFLATE's stored
 * blocks and the TIFF's tile index: DEFLATE never grows data by more, and
 * a scene is refused only when even incompressible pixels would not fit
 * (aerial scenes compress to about half, so most refused would have
 * fitted only by luck). A COG also holds overviews (1/3 more) and, while
 * GDAL's COG driver copies it, two files at once: twice that. */
static int check_disk(const char *path, int w, int h, int cog, char *err) {
  char dir[4096];
  snprintf(dir, sizeof(dir), "%s", path);
  char *slash = strrchr(dir, '/');
  if (slash == NULL) snprintf(dir, sizeof(dir), ".");
  else slash[slash == dir] = '\0';
  struct statvfs fs;
  if (statvfs(dir, &fs) != 0) return 0; /* the output's creation names the problem */
  double raw = (double)w * (double)h * (strcasecmp(ts_path_ext(path), "exr") == 0 ? 6 : 3);
  double need = (raw + raw / 64 + (1 << 20)) * (cog ? 2.0 * 4 / 3 : 1), avail = (double)fs.f_bavail * (double)fs.f_frsize;
  if (need <= avail) return 0;
  return ts_error(err, TS_ETOOBIG, "%s: the %dx%d scene may take up to %.1f MB (its samples uncompressed%s), and "
                  "%s has %.1f MB free: free some space or write the output elsewhere", path, w, h, need / 1e6,
                  cog ? ", with overviews, twice while the COG is copied" : "", dir, avail / 1e6);
}

static int open_io(tiler *t, const ts_image *const *in, const char *out_path, char *err) {
  const aerial_job *p = t->p;
  if (out_path == NULL) return ts_error(err, TS_EINVAL, "the aerial engine needs its output's path to stream it to");
  int rc = ts_aerial_open_sources(p, in, &t->meta, &t->map, &t->lines, &t->rules, err);
  if (rc != 0) return rc;
  if (ts_tile_grid_init(&t->g, t->map->width, t->map->height, p->tile, ts_aerial_halo(p)) != 0)
    return ts_error(err, TS_EINVAL, "--classes: an empty class map");
  size_t row = (size_t)t->g.w * READ_ROWS;
  t->ids = malloc(sizeof(int32_t) * row);
  t->values = malloc(sizeof(int32_t) * row);
  if (t->ids == NULL || t->values == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  if ((rc = check_disk(out_path, t->g.w, t->g.h, p->cog, err)) != 0) return rc;
  if (t->h->preview_path != NULL && (rc = ts_preview_open(&t->preview, t->h->preview_path, t->g.w, t->g.h, 3, err)) != 0)
    return rc;
  return ts_tile_sink_open(out_path, t->g.w, t->g.h, file_tile(p->tile), t->map, t->meta, p->cog, &t->sink, err);
}

static void tiler_free(tiler *t, int ok) {
  for (int r = 0; r < TS_FILL_MAX_CLASSES; r++) {
    free(t->ref_rgb[r]);
    free(t->ref_luma[r]);
  }
  for (int k = 0; k < BANDS; k++) {
    free(t->bands[k].state);
    free(t->bands[k].luma);
    free(t->bands[k].rgb);
    free(t->bands[k].src);
  }
  free(t->rank_of_id);
  free(t->colour_of_id);
  free(t->ids);
  free(t->values);
  if (t->map != NULL) t->map->close(t->map);
  if (t->lines != NULL) t->lines->close(t->lines);
  free(t->rules);
  ts_preview_close(t->preview);
  ts_meta_free(t->meta);
  if (!ok && t->sink != NULL) t->sink->abort(t->sink);
}

/* One step: the tiles of a row of one column parity, side by side on the
 * run's threads; their figures counted in tile order, the rows finished
 * written. */
static int run_step(tiler *t, const ts_tile_step *s, char *err) {
  /* The rows the step reads: its own, and for phases 2 and 3 the even
   * rows around. Read top to bottom - an even row's step reads the odd row
   * above it first - so the class map is read forwards only (a PNG decodes
   * no other way; reading back would decode it again from its start). */
  int rc = 0, last = s->row + (s->row & 1) < t->g.ny ? s->row + (s->row & 1) : t->g.ny - 1;
  for (int r = s->row > 0 ? s->row - 1 : 0; rc == 0 && r <= last; r++) rc = band_load(t, r, err);
  int ntiles = (t->g.nx - s->xpar + 1) / 2, nthreads = t->jobs < ntiles ? t->jobs : ntiles;
  aerial_piece *figs = rc == 0 ? calloc((size_t)(ntiles > 0 ? ntiles : 1), sizeof(*figs)) : NULL;
  if (rc == 0 && figs == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory");
  if (rc != 0 || ntiles == 0) {
    free(figs);
    return rc;
  }
  t->row = s->row;
  t->phase = ts_tile_phase(s->xpar, s->row);
  t->step_done0 = t->tiles_done;
  atomic_int next = 0;
  tile_worker w[AERIAL_MAX_TILE_JOBS];
  pthread_t th[AERIAL_MAX_TILE_JOBS];
  int started = 0;
  for (int i = 0; i < nthreads; i++)
    w[i] = (tile_worker){t, i, t->sessions[i], *s, &next, figs, err, &rc};
  /* Thread 0 is this one; the others are started for the step. */
  for (int i = 1; i < nthreads; i++, started++)
    if (pthread_create(&th[i], NULL, step_worker, &w[i]) != 0) break;
  step_worker(&w[0]);
  for (int i = 1; i <= started; i++) pthread_join(th[i], NULL);
  for (int k = 0; rc == 0 && k < ntiles; k++) add_stats(t, &figs[k]);
  free(figs);
  if (rc == 0) band_of_row(t, s->row)->tiles_done += ntiles;
  return rc == 0 ? write_rows(t, err) : rc;
}

static void add_search_stats(ts_search_stats *to, const ts_search_stats *s) {
  to->batches += s->batches;
  to->queries += s->queries;
  to->pairs += s->pairs;
  to->full_pairs += s->full_pairs;
  to->scan_seconds += s->scan_seconds;
  to->bytes_out += s->bytes_out;
  to->bytes_in += s->bytes_in;
  to->round_trips += s->round_trips;
}

/* The threads of the run and their sessions: --tile-jobs, or the cores,
 * at most the tiles of a step; one if the backend has no sessions. */
static int open_sessions(tiler *t, ts_search *search, char *err) {
  int want = t->p->tile_jobs > 0 ? t->p->tile_jobs : (int)sysconf(_SC_NPROCESSORS_ONLN);
  int most = (t->g.nx + 1) / 2;
  want = want < 1 ? 1 : want > most ? most : want > AERIAL_MAX_TILE_JOBS ? AERIAL_MAX_TILE_JOBS : want;
  t->sessions[0] = search;
  t->jobs = 1;
  for (int i = 1; i < want; i++) {
    int rc = ts_search_session(search, &t->sessions[i], err);
    if (rc == TS_ENOTSUP) break;
    if (rc != 0) return rc;
    t->jobs++;
  }
  return 0;
}

int ts_aerial_run_tiles(const aerial_job *p, const ts_image *const *in, ts_search *search,
                        const ts_engine_hooks *hooks, aerial_stats *st, char *err) {
  double t0 = ts_now();
  tiler t;
  memset(&t, 0, sizeof(t));
  memset(st, 0, sizeof(*st));
  t.p = p;
  t.h = hooks;
  t.st = st;
  for (int k = 0; k < BANDS; k++) t.bands[k].row = -1;
  const char *out_path = hooks->output_paths ? hooks->output_paths[AERIAL_OUT_IMAGE] : NULL;
  pthread_mutex_init(&t.lock, NULL);
  int rc = build_tables(&t, in, err);
  if (rc == 0) rc = open_io(&t, in, out_path, err);
  if (rc == 0) rc = open_sessions(&t, search, err);
  ts_tile_step *steps = rc == 0 ? malloc(sizeof(*steps) * 2 * (size_t)t.g.ny) : NULL;
  if (rc == 0 && steps == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory");
  int nsteps = rc == 0 ? ts_tile_schedule(&t.g, steps) : 0;
  st->nx = t.g.nx;
  st->ny = t.g.ny;
  st->halo = t.g.halo;
  st->tile_jobs = t.jobs;
  for (int k = 0; rc == 0 && k < nsteps; k++) rc = run_step(&t, &steps[k], err);
  if (rc == 0 && t.next_write != t.g.ny) rc = ts_error(err, TS_EINVAL, "internal: %d of %d tile rows written", t.next_write, t.g.ny);
  if (rc == 0) rc = t.sink->finish(t.sink, err);
  free(steps);
  st->tiles_resumed = (uint64_t)t.resumed;
  for (int i = 1; i < t.jobs; i++) {
    add_search_stats(&search->stats, &t.sessions[i]->stats); /* the run's figures are its sessions' too */
    ts_search_destroy(t.sessions[i]);
  }
  tiler_free(&t, rc == 0);
  pthread_mutex_destroy(&t.lock);
  st->seconds = ts_now() - t0;
  return rc;
}
