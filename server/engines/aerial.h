/* aerial.h - the aerial engine's parameters and its tiled run, shared by
 * aerial_engine.c (the table, spec, checks, report) and aerial_tiles.c
 * (the run: tiles, phases, bands, the streamed output). Private to the
 * engine. */
#ifndef TS_AERIAL_H
#define TS_AERIAL_H

#include <stdint.h>

#include "engine.h"
#include "fill.h"
#include "gis.h"
#include "region.h"

#define AERIAL_NAME_LEN 64
#define AERIAL_MAX_COLOURS 256
#define AERIAL_MAX_ID 65535
/* The class map, a reference per class and the lines are the inputs. */
#define AERIAL_MAX_CLASSES (TS_ENGINE_MAX_INPUTS - 2)

enum { AERIAL_STOCHASTIC = 0, AERIAL_STRUCTURED = 1 };
enum { AERIAL_OUT_IMAGE, AERIAL_OUT_REPORT, AERIAL_OUT_COUNT };

typedef struct {
  int id, kind;
  double usage_weight;
  char name[AERIAL_NAME_LEN];
} aerial_class;

typedef struct {
  int value;
  uint8_t rgb[3];
} aerial_colour;

typedef struct {
  ts_fill_params fill;
  int tile, halo; /* the grid (tile_grid.h); halo 0: derived */
  int tile_jobs;  /* tiles of one step at once; 0: the machine's cores */
  int nclass;     /* in the catalogue's order */
  aerial_class cls[TS_FILL_MAX_CLASSES];
  int lines;  /* a line raster is an input */
  int vector; /* the lines are a vector layer, drawn by the catalogue's rules */
  int ncolours;
  aerial_colour colour[AERIAL_MAX_COLOURS];
  uint64_t max_pixels; /* of a tile's synthesis area */
  int cog;             /* the output, a .tif, as a Cloud-Optimised GeoTIFF */
} aerial_job;

/* The halo a job uses: its own, or the one its pyramid needs. */
int ts_aerial_halo(const aerial_job *p);
/* The colour index of a line value, or -1. */
int ts_aerial_colour_of(const aerial_job *p, int v);
/* The catalogue index of a class id, or -1. */
int ts_aerial_class_of(const aerial_job *p, int id);
/* Classes in fill order - stochastic first, then structured, each in the
 * catalogue's order: order[r] is the catalogue index of rank r. */
void ts_aerial_fill_order(const aerial_job *p, int *order);
/* The input index of the line raster (p->lines), and whether input k is
 * read by regions (the class map and the line raster). */
static inline int ts_aerial_lines_input(const aerial_job *p) { return 1 + p->nclass; }
int ts_aerial_by_regions(const void *params, int k);
/* With p->vector, the catalogue the line rules are read from is the input
 * after the vector layer; both are files the engine opens itself. */
static inline int ts_aerial_rules_input(const aerial_job *p) { return 2 + p->nclass; }

/* The class map and the lines opened by regions: the lines a line raster,
 * or a vector layer rasterised at the map's grid and georeferencing by
 * the rules (*rules, malloc'd, NULL without a vector layer). meta as
 * ts_region_source_open's (may be NULL). On failure nothing is left open. */
int ts_aerial_open_sources(const aerial_job *p, const ts_image *const *in, ts_meta **meta, ts_region_source **map,
                           ts_region_source **lines, ts_gis_line_rules **rules, char *err);
/* Lines hidden under classes (the rules' hidden_under): values[i] becomes
 * 0 where the line is hidden under class ids[i]. n pixels. */
void ts_aerial_lines_hide(const ts_gis_line_rules *rules, const int32_t *ids, int32_t *values, size_t n);

/* What a run did, summed over its tiles, for the report. */
typedef struct {
  int nx, ny, halo, tile_jobs;
  uint64_t tiles_filled;  /* tiles with anything to synthesise */
  uint64_t tiles_resumed; /* tiles taken from an earlier run's pieces */
  double seconds;
  ts_fill_level_stats level[TS_FILL_MAX_LEVELS];
  uint64_t blocks[TS_FILL_MAX_CLASSES]; /* per rank, level 0 */
  /* Per rank: the tiles' usage means and variances, weighted by the
   * class's blocks in each tile (each tile's usage is its own). */
  double usage_mean[TS_FILL_MAX_CLASSES], usage_variance[TS_FILL_MAX_CLASSES];
} aerial_stats;

/* ---- a finished tile as a checkpoint piece (aerial_piece.c) ----------------
 *
 * Saved through hooks->save_piece as its tile finishes, found again by a
 * run of the same job after a restart: the tile's own pixels (their
 * luminance, which later tiles' halos give, their colours and copies) and its
 * share of the report's figures. Self-checking (a checksum, the job's
 * tag, the tile's place): anything else is refused and the tile made
 * again, which gives the same bytes. */
#define AERIAL_EDIT_BYTES 17

typedef struct {
  uint32_t index;            /* the tile's (ts_tile_index) */
  int x0, y0, w, h;          /* its core */
  const uint8_t *luma, *rgb; /* w * h and 3 * w * h bytes, rows `stride` pixels apart */
  /* Where each pixel was copied from in its class's reference (y * width
   * + x; the seam cut of later tiles joins to it): to encode, w * h
   * values, rows `stride` apart; decoded, 4 * w * h little-endian bytes. */
  const uint32_t *src;
  const uint8_t *src_le;
  size_t stride;
  /* The seam cut's changes to the tile's halo (the neighbours' pixels next
   * to its core), a resumed tile applies them again: nedits of
   * AERIAL_EDIT_BYTES each, u32 x, y (the scene's), class rank, copy,
   * and u8 luminance, little-endian. */
  uint32_t nedits;
  const uint8_t *edits;
  int nclass;                                /* classes filled in it */
  int rank[TS_FILL_MAX_CLASSES];             /* their fill ranks */
  ts_fill_class_stats cls[TS_FILL_MAX_CLASSES];
  ts_fill_level_stats level[TS_FILL_MAX_LEVELS]; /* blocks, steps, seeds, comparisons */
} aerial_piece;

/* The piece's bytes (malloc'd) for a job of `levels` levels tagged `tag`. */
int ts_aerial_piece_encode(const aerial_piece *pc, int levels, uint64_t tag, uint8_t **buf, size_t *len);
/* Decodes a piece of tile `index` with core (x0, y0, w, h) of that job:
 * 0 with pc's pixels pointing into buf (stride w), or TS_EPROTO with the
 * reason in err. */
int ts_aerial_piece_decode(const uint8_t *buf, size_t len, int levels, uint64_t tag, uint32_t index, int x0, int y0,
                           int w, int h, aerial_piece *pc, char *err);

/* Runs the job tile by tile (aerial_tiles.c), streaming the image to
 * hooks->output_paths[AERIAL_OUT_IMAGE]. in[] as run gets them. */
int ts_aerial_run_tiles(const aerial_job *p, const ts_image *const *in, ts_search *search,
                        const ts_engine_hooks *hooks, aerial_stats *st, char *err);

#endif
