/* tile_grid.h - a large scene cut into tiles (DESIGN.md §4b "Tiles"): the
 * fixed grid, the phases, the order tiles are synthesised in and each
 * tile's seed. Everything here is a function of the scene's size and the
 * job's parameters alone - never of the pool, the threads or how many
 * tiles run at once - so a tiled job gives the same bytes wherever it runs.
 *
 * The grid: tiles of `tile` x `tile` pixels from the top-left corner; the
 * last column (row) takes the remainder, or, when that is under half a
 * tile, is merged into the one before it (a tile up to 1.5 tiles wide), so
 * no tile is a sliver too small for the pyramid's coarsest level. Tile
 * origins are multiples of `tile`.
 *
 * The phases: a 2 x 2 checkerboard, phase = 2 * (ty % 2) + tx % 2. Tiles
 * of one phase share no edge. A tile of phase p reads only tiles of earlier
 * phases, through its halo: its synthesis area is its core grown by the
 * halo across the edges whose neighbours are of an earlier phase - phase 0
 * not at all, phase 1 left and right (phase-0 neighbours), phase 2 up and
 * down (phase-0 neighbours, phase-1 corners), phase 3 on all four sides
 * (every neighbour finished) - clipped to the scene. Every pixel of the
 * area outside the core is finished when the tile starts, so the area is a
 * rectangle of given pixels around the work: constrained synthesis (the
 * fill engine's state 0) joins the tile to its neighbours, and every edge
 * between two tiles is joined from one side.
 *
 * The order: a wavefront over tile rows, so only three rows are alive at
 * once (bounded memory): for every even row r, phases 0 and 1 of row r,
 * then phases 2 and 3 of row r - 1. A step is one phase of one row; its
 * tiles are independent (they may run side by side), and each reads only
 * finished tiles, exactly those the plain phase order (all of phase 0, then
 * all of phase 1, ...) would have finished: the order changes the memory a
 * job takes, never a pixel. */
#ifndef TS_TILE_GRID_H
#define TS_TILE_GRID_H

#include <stdint.h>

/* Largest tile side: a tile is one fill; its copy map and pyramid take
 * some 16 bytes a pixel. */
#define TS_TILE_MAX 16384

typedef struct {
  int x0, y0, x1, y1; /* [x0, x1) x [y0, y1) */
} ts_tile_rect;

typedef struct {
  int w, h;       /* the scene */
  int tile, halo; /* grid spacing and halo width, pixels */
  int nx, ny;     /* tiles across and down */
} ts_tile_grid;

/* One step of the order: the tiles of row `row` whose column has parity
 * `xpar` (phase 2 * (row % 2) + xpar). */
typedef struct {
  int row, xpar;
} ts_tile_step;

/* The halo a job uses when none is given. Its reach: the coarsest
 * level's neighbourhood reaches wn / 2 pixels of that level past a block,
 * each 2^(levels - 1) scene pixels, and one coarse pixel more keeps the
 * masked Gaussian of the level below (which needs whole 2 x 2 cells given)
 * inside finished pixels: (wn / 2 + 1) * 2^(levels - 1). Its alignment:
 * the next multiple of 2^(levels - 1) (the neighbours' pyramids line up)
 * that is one short of a multiple of wb, so that the later tile's block
 * grid, which starts at its area's edge, puts a block across the border
 * with wb - 1 of its columns on the finished side: that block is matched
 * against the finished pixels it overlaps, and the border joins as well as
 * two blocks of one tile do (bench/tile_seams.py: with the border on a
 * block edge, 1.17x the mean difference of block seams; so aligned,
 * 1.00-1.05x). The fill's seam cut (fill_seams.h) then moves both kinds of
 * join to where the copies agree (aerial_tiles.c). 20 for the aerial
 * defaults (3 levels, wn 7, wb 3). */
int ts_tile_default_halo(int levels, int wn, int wb);

/* The grid of a w x h scene: 0, or TS_EINVAL for sizes < 1 (tile and halo
 * are the engine's to check: ts_tile_grid_check). */
int ts_tile_grid_init(ts_tile_grid *g, int w, int h, int tile, int halo);

/* Number of tiles, and tile (tx, ty)'s index (row-major). */
static inline int ts_tile_count(const ts_tile_grid *g) { return g->nx * g->ny; }
static inline int ts_tile_index(const ts_tile_grid *g, int tx, int ty) { return ty * g->nx + tx; }

/* Column tx's pixels [*x0, *x1) (rows alike: ts_tile_span with g->h). */
void ts_tile_span(int size, int tile, int n, int t, int *x0, int *x1);

/* Tile (tx, ty)'s own pixels. */
ts_tile_rect ts_tile_core(const ts_tile_grid *g, int tx, int ty);
/* Its synthesis area: the core and the finished halo around it (above). */
ts_tile_rect ts_tile_area(const ts_tile_grid *g, int tx, int ty);
static inline int ts_tile_phase(int tx, int ty) { return 2 * (ty & 1) + (tx & 1); }

/* The order's steps: 2 * g->ny of them into steps (room for that many);
 * returns the count. */
int ts_tile_schedule(const ts_tile_grid *g, ts_tile_step *steps);

/* The seed of tile `index` of a job seeded `seed`: splitmix64's finaliser
 * of seed + (index + 1) * 0x9E3779B97F4A7C15 (the golden-ratio increment),
 * so neighbouring tiles and neighbouring job seeds get unrelated streams. */
uint64_t ts_tile_seed(uint64_t seed, uint32_t index);

#endif
