/* patchmatch.c - tile sweeps of the PatchMatch field (patchmatch.h). */
#include <stdlib.h>
#include <string.h>
#ifdef __SSE2__
#include <emmintrin.h>
#endif

#include "error.h"
#include "patchmatch.h"
#include "rng.h"
#include "usage.h"

#define SLACK 16 /* bytes readable past a packed part (one 16-byte load) */

/* ---- packing ----------------------------------------------------------- */

int ts_pm_window_check(const ts_window *win, int *patch, char *err) {
  const ts_window_spec *s = &win->spec;
  int n = s->noff[TS_SRC_FINE], p = 1;
  while (p * p < n) p++;
  if (p * p != n || s->noff[TS_SRC_COARSE] != 0)
    return ts_error(err, TS_EINVAL, "patchmatch needs a square window over fine planes");
  for (int i = 0; i < n; i++)
    if (s->dx[TS_SRC_FINE][i] != i % p || s->dy[TS_SRC_FINE][i] != i / p)
      return ts_error(err, TS_EINVAL, "patchmatch needs the window's offsets in row order from (0, 0)");
  for (int k = 0; k < s->nparts; k++)
    if (s->part[k].source != TS_SRC_FINE)
      return ts_error(err, TS_EINVAL, "patchmatch needs every part on fine planes");
  *patch = p;
  return 0;
}

int ts_pm_image_pack(ts_pm_image *im, const ts_window *win, const ts_plane *const *planes) {
  const ts_window_spec *s = &win->spec;
  memset(im, 0, sizeof(*im));
  im->w = planes[0]->w;
  im->h = planes[0]->h;
  im->nparts = s->nparts;
  size_t n = (size_t)im->w * (size_t)im->h;
  for (int k = 0; k < s->nparts; k++) {
    int ch = s->part[k].nplanes;
    im->ch[k] = (uint8_t)ch;
    uint8_t *d = malloc(n * (size_t)ch + SLACK);
    if (d == NULL) {
      ts_pm_image_free(im);
      return TS_ENOMEM;
    }
    memset(d + n * (size_t)ch, 0, SLACK);
    for (int c = 0; c < ch; c++) {
      const uint8_t *px = planes[s->part[k].plane0 + c]->px;
      for (size_t i = 0; i < n; i++) d[i * (size_t)ch + (size_t)c] = px[i];
    }
    im->part[k] = d;
  }
  return 0;
}

void ts_pm_image_free(ts_pm_image *im) {
  for (int k = 0; k < TS_L1_MAX_PARTS; k++) free(im->part[k]);
  memset(im, 0, sizeof(*im));
}

/* ---- distance ---------------------------------------------------------- */

static uint32_t sad_scalar(const uint8_t *a, const uint8_t *b, int n) {
  uint32_t s = 0;
  for (int i = 0; i < n; i++) s += (uint32_t)(a[i] > b[i] ? a[i] - b[i] : b[i] - a[i]);
  return s;
}

#ifdef __SSE2__
/* 16 bytes of 0xFF then 16 of 0: the mask of the first m bytes of a load
 * starts at 16 - m. Both sides are masked, so bytes past the span add 0. */
static const uint8_t kHeadMask[32] = {255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255,
                                      255, 255, 255, 255, 255};

static uint32_t sad_sse2(const uint8_t *a, const uint8_t *b, int n) {
  __m128i acc = _mm_setzero_si128();
  int i = 0;
  for (; i + 16 <= n; i += 16)
    acc = _mm_add_epi64(acc, _mm_sad_epu8(_mm_loadu_si128((const __m128i *)(a + i)),
                                          _mm_loadu_si128((const __m128i *)(b + i))));
  if (i < n) {
    __m128i m = _mm_loadu_si128((const __m128i *)(kHeadMask + 16 - (n - i)));
    __m128i x = _mm_and_si128(_mm_loadu_si128((const __m128i *)(a + i)), m);
    __m128i y = _mm_and_si128(_mm_loadu_si128((const __m128i *)(b + i)), m);
    acc = _mm_add_epi64(acc, _mm_sad_epu8(x, y));
  }
  return (uint32_t)(_mm_cvtsi128_si32(acc) + _mm_cvtsi128_si32(_mm_unpackhi_epi64(acc, acc)));
}
#define SAD_FAST sad_sse2
#else
#define SAD_FAST sad_scalar
#endif

typedef uint32_t sad_fn(const uint8_t *a, const uint8_t *b, int n);

/* What a sweep reads, resolved once per tile. */
typedef struct {
  const ts_pm_pass *ps;
  sad_fn *sad;
  int p, r, sw, nx; /* nx: source patches per row */
  int cx_max, cy_max;
  int tgt_w;
  const int32_t *du;
} sweep;

/* Index of the source patch centred at (cx, cy): its anchor index. */
static inline uint32_t patch_index(const sweep *sw, uint32_t cx, uint32_t cy) {
  return (cy - (uint32_t)sw->r) * (uint32_t)sw->nx + (cx - (uint32_t)sw->r);
}

/* Distance of target pixel (x, y) to the source patch centred at (cx, cy),
 * stopping early once it exceeds bound (the value returned is then only
 * known to exceed it). */
static uint64_t distance(const sweep *sw, int x, int y, uint32_t cx, uint32_t cy, uint64_t bound) {
  const ts_pm_pass *ps = sw->ps;
  uint64_t d = 0;
  if (ps->k != 0) {
    uint32_t j = patch_index(sw, cx, cy);
    d = ts_usage_penalty((uint32_t)((int64_t)ps->ublock[j] + sw->du[j]), ps->k);
  }
  int sx = (int)cx - sw->r, sy = (int)cy - sw->r;
  for (int k = 0; k < ps->src->nparts && d <= bound; k++) {
    int ch = ps->src->ch[k], span = sw->p * ch;
    const uint8_t *t = ps->tgt->part[k] + ((size_t)y * (size_t)sw->tgt_w + (size_t)x) * (size_t)ch;
    const uint8_t *s = ps->src->part[k] + ((size_t)sy * (size_t)sw->sw + (size_t)sx) * (size_t)ch;
    uint32_t sum = 0;
    for (int row = 0; row < sw->p; row++)
      sum += sw->sad(t + (size_t)row * (size_t)sw->tgt_w * (size_t)ch, s + (size_t)row * (size_t)sw->sw * (size_t)ch,
                     span);
    d += (uint64_t)ps->win->spec.part[k].weight * sum;
  }
  return d;
}

/* ---- occurrences ------------------------------------------------------- */

void ts_pm_occurrences(const uint32_t *field, size_t n, int p, int sw, int sh, uint32_t *counts) {
  int r = p / 2;
  memset(counts, 0, (size_t)sw * (size_t)sh * sizeof(*counts));
  for (size_t i = 0; i < n; i++) {
    uint32_t *row = counts + ((size_t)field[2 * i + 1] - (size_t)r) * (size_t)sw + field[2 * i] - (size_t)r;
    for (int y = 0; y < p; y++, row += sw)
      for (int x = 0; x < p; x++) row[x]++;
  }
}

void ts_pm_block_sums(const uint32_t *counts, int p, int sw, int sh, uint32_t *col, uint32_t *ublock) {
  int nx = sw - p + 1;
  memset(col, 0, (size_t)sw * sizeof(*col)); /* column sums over the last p rows */
  for (int y = 0; y < sh; y++) {
    for (int x = 0; x < sw; x++) {
      col[x] += counts[(size_t)y * (size_t)sw + (size_t)x];
      if (y >= p) col[x] -= counts[(size_t)(y - p) * (size_t)sw + (size_t)x];
    }
    if (y < p - 1) continue;
    uint32_t s = 0;
    for (int x = 0; x < sw; x++) {
      s += col[x];
      if (x >= p) s -= col[x - p];
      if (x >= p - 1) ublock[(size_t)(y - p + 1) * (size_t)nx + (size_t)(x - p + 1)] = s;
    }
  }
}

/* ---- the tile's own moves ---------------------------------------------- */

/* U_j of every source patch overlapping patch j0 changes by delta times
 * the overlap's area. */
static void du_move(const sweep *sw, int32_t *du, int ny, uint32_t j0, int delta) {
  int p = sw->p, jx = (int)(j0 % (uint32_t)sw->nx), jy = (int)(j0 / (uint32_t)sw->nx);
  for (int dy = -(p - 1); dy <= p - 1; dy++) {
    int y = jy + dy;
    if (y < 0 || y >= ny) continue;
    int oy = p - (dy < 0 ? -dy : dy);
    for (int dx = -(p - 1); dx <= p - 1; dx++) {
      int x = jx + dx;
      if (x < 0 || x >= sw->nx) continue;
      du[(size_t)y * (size_t)sw->nx + (size_t)x] += delta * oy * (p - (dx < 0 ? -dx : dx));
    }
  }
}

static int scratch_ready(ts_pm_scratch *scr, size_t npatches) {
  if (scr->du == NULL) {
    scr->du = calloc(npatches, sizeof(*scr->du));
    if (scr->du == NULL) return TS_ENOMEM;
  }
  scr->nmoves = 0;
  return 0;
}

static int log_move(ts_pm_scratch *scr, uint32_t from, uint32_t to) {
  if (scr->nmoves + 2 > scr->cap) {
    size_t cap = scr->cap ? 2 * scr->cap : 4096;
    uint32_t *m = realloc(scr->moves, cap * sizeof(*m));
    if (m == NULL) return TS_ENOMEM;
    scr->moves = m;
    scr->cap = cap;
  }
  scr->moves[scr->nmoves++] = from;
  scr->moves[scr->nmoves++] = to;
  return 0;
}

void ts_pm_scratch_free(ts_pm_scratch *scr) {
  free(scr->du);
  free(scr->moves);
  memset(scr, 0, sizeof(*scr));
}

/* ---- the sweep --------------------------------------------------------- */

int ts_pm_tiles(int tw, int th) {
  return ((tw + TS_PM_TILE - 1) / TS_PM_TILE) * ((th + TS_PM_TILE - 1) / TS_PM_TILE);
}

typedef struct {
  uint64_t d;
  uint32_t cx, cy, index;
} best_t;

static void try_centre(const sweep *sw, int x, int y, long cx, long cy, best_t *b) {
  if (cx < sw->r || cy < sw->r || cx > sw->cx_max || cy > sw->cy_max) return;
  uint32_t j = patch_index(sw, (uint32_t)cx, (uint32_t)cy);
  if (j == b->index) return;
  uint64_t d = distance(sw, x, y, (uint32_t)cx, (uint32_t)cy, b->d);
  if (d < b->d || (d == b->d && j < b->index)) *b = (best_t){d, (uint32_t)cx, (uint32_t)cy, j};
}

static long clampl(long v, long lo, long hi) { return v < lo ? lo : v > hi ? hi : v; }

/* The match of neighbour (nx, ny) of (x, y), shifted by the step back to
 * (x, y): from this pass when it lies in the tile, else from the input. */
static void try_neighbour(const sweep *sw, const uint32_t *out, int x0, int y0, int x1, int y1, int x, int y, int nbx,
                          int nby, best_t *b) {
  const ts_pm_pass *ps = sw->ps;
  if (nbx < 0 || nby < 0 || nbx >= ps->tw || nby >= ps->th) return;
  int inside = nbx >= x0 && nbx < x1 && nby >= y0 && nby < y1;
  const uint32_t *f = (inside ? out : ps->in) + 2 * ((size_t)nby * (size_t)ps->tw + (size_t)nbx);
  try_centre(sw, x, y, (long)f[0] + (x - nbx), (long)f[1] + (y - nby), b);
}

static void random_search(const sweep *sw, ts_rng *rng, int x, int y, best_t *b) {
  long radius = sw->ps->src->w > sw->ps->src->h ? sw->ps->src->w : sw->ps->src->h;
  for (; radius >= 1; radius /= 2) {
    long cx = (long)b->cx + (long)ts_rng_below(rng, (uint32_t)(2 * radius + 1)) - radius;
    long cy = (long)b->cy + (long)ts_rng_below(rng, (uint32_t)(2 * radius + 1)) - radius;
    try_centre(sw, x, y, clampl(cx, sw->r, sw->cx_max), clampl(cy, sw->r, sw->cy_max), b);
  }
}

uint64_t ts_pm_sweep_tile(const ts_pm_pass *ps, int t, ts_pm_scratch *scr, uint32_t *out, int *rc) {
  int p = ps->patch, r = p / 2, sw_ = ps->src->w, sh = ps->src->h;
  int ntx = (ps->tw + TS_PM_TILE - 1) / TS_PM_TILE;
  int x0 = (t % ntx) * TS_PM_TILE, y0 = (t / ntx) * TS_PM_TILE;
  int x1 = x0 + TS_PM_TILE < ps->tw ? x0 + TS_PM_TILE : ps->tw;
  int y1 = y0 + TS_PM_TILE < ps->th ? y0 + TS_PM_TILE : ps->th;
  int ny = sh - p + 1;
  *rc = ps->k != 0 ? scratch_ready(scr, (size_t)(sw_ - p + 1) * (size_t)ny) : 0;
  if (*rc != 0) return 0;
  sweep sw = {ps, ps->scalar ? sad_scalar : SAD_FAST, p, r, sw_, sw_ - p + 1, sw_ - 1 - r, sh - 1 - r,
              ps->tw + p - 1, scr->du};
  ts_rng rng;
  ts_rng_seed(&rng, ps->seed, ((uint64_t)ps->pass << 32) | (uint32_t)t);
  int back = ps->pass & 1, step = back ? -1 : 1;
  uint64_t total = 0;
  for (int i = 0; i < y1 - y0; i++) {
    int y = back ? y1 - 1 - i : y0 + i;
    for (int jj = 0; jj < x1 - x0; jj++) {
      int x = back ? x1 - 1 - jj : x0 + jj;
      const uint32_t *cur = ps->in + 2 * ((size_t)y * (size_t)ps->tw + (size_t)x);
      best_t b = {0, cur[0], cur[1], patch_index(&sw, cur[0], cur[1])};
      b.d = distance(&sw, x, y, b.cx, b.cy, UINT64_MAX);
      uint32_t was = b.index;
      try_neighbour(&sw, out, x0, y0, x1, y1, x, y, x - step, y, &b);
      try_neighbour(&sw, out, x0, y0, x1, y1, x, y, x, y - step, &b);
      random_search(&sw, &rng, x, y, &b);
      uint32_t *o = out + 2 * ((size_t)y * (size_t)ps->tw + (size_t)x);
      o[0] = b.cx;
      o[1] = b.cy;
      total += b.d;
      if (ps->k == 0 || b.index == was) continue;
      if ((*rc = log_move(scr, was, b.index)) != 0) return 0;
      du_move(&sw, scr->du, ny, was, -1);
      du_move(&sw, scr->du, ny, b.index, 1);
    }
  }
  /* Undo the tile's moves so the scratch is zero for the next tile. */
  for (size_t m = 0; m < scr->nmoves; m += 2) {
    du_move(&sw, scr->du, ny, scr->moves[m], 1);
    du_move(&sw, scr->du, ny, scr->moves[m + 1], -1);
  }
  return total;
}
