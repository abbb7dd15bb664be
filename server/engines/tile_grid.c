/* tile_grid.c - see tile_grid.h. */
#include "tile_grid.h"

#include "error.h"

int ts_tile_default_halo(int levels, int wn, int wb) {
  int unit = 1 << (levels - 1), h = (wn / 2 + 1) * unit;
  while (wb > 1 && h % wb != wb - 1) h += unit; /* wb odd: found within wb steps */
  return h;
}

/* Tiles along a side: the remainder makes a tile of its own only when it
 * is at least half a tile. */
static int tiles_along(int size, int tile) {
  int n = (size + tile - 1) / tile, rest = size - (n - 1) * tile;
  return n > 1 && 2 * rest < tile ? n - 1 : n;
}

int ts_tile_grid_init(ts_tile_grid *g, int w, int h, int tile, int halo) {
  if (w < 1 || h < 1 || tile < 1 || halo < 0) return TS_EINVAL;
  *g = (ts_tile_grid){w, h, tile, halo, tiles_along(w, tile), tiles_along(h, tile)};
  return 0;
}

void ts_tile_span(int size, int tile, int n, int t, int *x0, int *x1) {
  *x0 = t * tile;
  *x1 = t + 1 == n ? size : *x0 + tile;
}

ts_tile_rect ts_tile_core(const ts_tile_grid *g, int tx, int ty) {
  ts_tile_rect r;
  ts_tile_span(g->w, g->tile, g->nx, tx, &r.x0, &r.x1);
  ts_tile_span(g->h, g->tile, g->ny, ty, &r.y0, &r.y1);
  return r;
}

static int clamp(int v, int lo, int hi) { return v < lo ? lo : v > hi ? hi : v; }

ts_tile_rect ts_tile_area(const ts_tile_grid *g, int tx, int ty) {
  ts_tile_rect r = ts_tile_core(g, tx, ty);
  int gx = tx & 1 ? g->halo : 0, gy = ty & 1 ? g->halo : 0;
  return (ts_tile_rect){clamp(r.x0 - gx, 0, g->w), clamp(r.y0 - gy, 0, g->h), clamp(r.x1 + gx, 0, g->w),
                        clamp(r.y1 + gy, 0, g->h)};
}

int ts_tile_schedule(const ts_tile_grid *g, ts_tile_step *steps) {
  int n = 0;
  for (int r = 0; r <= g->ny; r += 2) {
    if (r < g->ny) {
      steps[n++] = (ts_tile_step){r, 0};
      steps[n++] = (ts_tile_step){r, 1};
    }
    if (r >= 1) {
      steps[n++] = (ts_tile_step){r - 1, 0};
      steps[n++] = (ts_tile_step){r - 1, 1};
    }
  }
  return n;
}

uint64_t ts_tile_seed(uint64_t seed, uint32_t index) {
  uint64_t z = seed + ((uint64_t)index + 1) * 0x9E3779B97F4A7C15ull;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}
