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

#define MAX_PATCH 45 /* p * p offsets fit TS_WIN_MAX_OFFSETS */

/* ---- distance ---------------------------------------------------------- */

/* Where part k of a patch lies: the packed planes of source and target and
 * their strides; with SSE2, how the target's rows are cut into 16-byte
 * chunks. */
typedef struct {
  const uint8_t *src, *tgt;
  size_t src_row, tgt_row; /* bytes per image row */
  uint32_t ch, span;       /* bytes per pixel, per patch row */
  uint32_t nchunks;        /* 16-byte chunks per patch row */
  uint64_t weight;
} part_geom;

/* What a sweep reads, resolved once per tile. */
typedef struct {
  const ts_pm_pass *ps;
  int p, r, nx, ny; /* nx x ny source patches */
  int cx_max, cy_max;
  int nparts, scalar;
  part_geom part[TS_L1_MAX_PARTS];
  uint32_t *usage; /* U_j now (scratch): NULL without a penalty */
  uint64_t k;
  uint32_t tent[2 * MAX_PATCH]; /* p - |i - (p - 1)|: overlaps along an axis */
  uint8_t *query; /* SSE2: the target patch, chunked and masked */
} sweep;

/* Index of the source patch centred at (cx, cy): its anchor index. */
static inline uint32_t patch_index(const sweep *sw, uint32_t cx, uint32_t cy) {
  return (cy - (uint32_t)sw->r) * (uint32_t)sw->nx + (cx - (uint32_t)sw->r);
}

static uint32_t sad_scalar(const uint8_t *a, const uint8_t *b, uint32_t n) {
  uint32_t s = 0;
  for (uint32_t i = 0; i < n; i++) s += (uint32_t)(a[i] > b[i] ? a[i] - b[i] : b[i] - a[i]);
  return s;
}

/* Weighted SAD of target pixel (x, y)'s patch and the source patch with
 * top-left pixel (sx, sy), plain loops: the reference the SIMD path must
 * match. Stops once the sum exceeds bound. */
static uint64_t patch_sad_scalar(const sweep *sw, int x, int y, int sx, int sy, uint64_t bound) {
  uint64_t d = 0;
  for (int k = 0; k < sw->nparts && d <= bound; k++) {
    const part_geom *g = &sw->part[k];
    const uint8_t *t = g->tgt + (size_t)y * g->tgt_row + (size_t)x * g->ch;
    const uint8_t *s = g->src + (size_t)sy * g->src_row + (size_t)sx * g->ch;
    uint32_t sum = 0;
    for (int row = 0; row < sw->p; row++, t += g->tgt_row, s += g->src_row) sum += sad_scalar(t, s, g->span);
    d += g->weight * sum;
  }
  return d;
}

#ifdef __SSE2__
/* 16 bytes of 0xFF then 16 of 0: the mask of the first m bytes of a load
 * starts at 16 - m. */
static const uint8_t kHeadMask[32] = {255, 255, 255, 255, 255, 255, 255, 255, 255, 255, 255,
                                      255, 255, 255, 255, 255};

static inline __m128i head_mask(uint32_t m) { return _mm_loadu_si128((const __m128i *)(kHeadMask + 16 - m)); }

/* Copies target pixel (x, y)'s patch into sw->query, each part row as
 * nchunks 16-byte chunks with the bytes past the span zeroed: it is read
 * by every candidate of the pixel. */
static void query_load_sse2(sweep *sw, int x, int y) {
  __m128i *q = (__m128i *)sw->query;
  for (int k = 0; k < sw->nparts; k++) {
    const part_geom *g = &sw->part[k];
    const uint8_t *t = g->tgt + (size_t)y * g->tgt_row + (size_t)x * g->ch;
    __m128i tail = head_mask(g->span - 16 * (g->nchunks - 1));
    for (int row = 0; row < sw->p; row++, t += g->tgt_row) {
      uint32_t c = 0;
      for (; c + 1 < g->nchunks; c++) _mm_store_si128(q++, _mm_loadu_si128((const __m128i *)(t + 16 * c)));
      _mm_store_si128(q++, _mm_and_si128(_mm_loadu_si128((const __m128i *)(t + 16 * c)), tail));
    }
  }
}

/* patch_sad_scalar against the query: source bytes past a row's span are
 * masked like the query's, so they add 0. */
static uint64_t patch_sad_sse2(const sweep *sw, int sx, int sy, uint64_t bound) {
  const __m128i *q = (const __m128i *)sw->query;
  uint64_t d = 0;
  for (int k = 0; k < sw->nparts && d <= bound; k++) {
    const part_geom *g = &sw->part[k];
    const uint8_t *s = g->src + (size_t)sy * g->src_row + (size_t)sx * g->ch;
    __m128i tail = head_mask(g->span - 16 * (g->nchunks - 1)), acc = _mm_setzero_si128();
    for (int row = 0; row < sw->p; row++, s += g->src_row) {
      uint32_t c = 0;
      for (; c + 1 < g->nchunks; c++)
        acc = _mm_add_epi64(acc, _mm_sad_epu8(_mm_loadu_si128((const __m128i *)(s + 16 * c)), _mm_load_si128(q++)));
      __m128i last = _mm_and_si128(_mm_loadu_si128((const __m128i *)(s + 16 * c)), tail);
      acc = _mm_add_epi64(acc, _mm_sad_epu8(last, _mm_load_si128(q++)));
    }
    uint32_t sum = (uint32_t)(_mm_cvtsi128_si32(acc) + _mm_cvtsi128_si32(_mm_unpackhi_epi64(acc, acc)));
    d += g->weight * sum;
  }
  return d;
}
#endif

/* Bytes of the SSE2 query of a window with patch p. */
static size_t query_bytes(const ts_pm_image *src, int p) {
  size_t n = 0;
  for (int k = 0; k < src->nparts; k++) n += (size_t)p * (((size_t)p * src->ch[k] + 15) / 16) * 16;
  return n;
}

/* Makes target pixel (x, y) the one candidates are compared with. */
static void query_load(sweep *sw, int x, int y) {
#ifdef __SSE2__
  if (!sw->scalar) query_load_sse2(sw, x, y);
#else
  (void)sw, (void)x, (void)y;
#endif
}

/* Distance of target pixel (x, y) (the loaded query) to the source patch
 * j centred at (cx, cy), stopping early once it exceeds bound (the value
 * returned is then only known to exceed it). The penalty comes last: a
 * candidate the patch already rules out never reads the usage. */
static uint64_t distance(const sweep *sw, int x, int y, uint32_t cx, uint32_t cy, uint32_t j, uint64_t bound) {
  int sx = (int)cx - sw->r, sy = (int)cy - sw->r;
  uint64_t d;
#ifdef __SSE2__
  if (!sw->scalar) d = patch_sad_sse2(sw, sx, sy, bound);
  else
#endif
    d = patch_sad_scalar(sw, x, y, sx, sy, bound);
  if (sw->usage != NULL && d <= bound) d += ts_usage_penalty(sw->usage[j], sw->k);
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

/* U_j of every source patch overlapping the one at anchor (ax, ay) changes
 * by delta times the overlap's area, (p - |dx|) * (p - |dy|). Unsigned
 * arithmetic wraps, so a move and its undoing cancel exactly. */
static void usage_move(const sweep *sw, int ax, int ay, int32_t delta) {
  int p = sw->p, reach = p - 1;
  int x0 = ax > reach ? ax - reach : 0, x1 = ax + p < sw->nx ? ax + p : sw->nx;
  int y0 = ay > reach ? ay - reach : 0, y1 = ay + p < sw->ny ? ay + p : sw->ny;
  const uint32_t *wx = sw->tent + (x0 - ax + reach);
  for (int y = y0; y < y1; y++) {
    uint32_t f = (uint32_t)delta * sw->tent[y - ay + reach];
    uint32_t *row = sw->usage + (size_t)y * (size_t)sw->nx + (size_t)x0;
    for (int i = 0; i < x1 - x0; i++) row[i] += f * wx[i];
  }
}

int ts_pm_scratch_begin(ts_pm_scratch *scr, const ts_pm_pass *ps) {
  size_t query = query_bytes(ps->src, ps->patch);
  if (query > scr->query_cap) {
    free(scr->query);
    scr->query = aligned_alloc(16, query);
    scr->query_cap = scr->query != NULL ? query : 0;
    if (scr->query == NULL) return TS_ENOMEM;
  }
  if (ps->k == 0) return 0;
  size_t n = (size_t)(ps->src->w - ps->patch + 1) * (size_t)(ps->src->h - ps->patch + 1);
  if (n > scr->usage_cap) {
    free(scr->usage);
    scr->usage = malloc(n * sizeof(*scr->usage));
    scr->usage_cap = scr->usage != NULL ? n : 0;
    if (scr->usage == NULL) return TS_ENOMEM;
  }
  memcpy(scr->usage, ps->ublock, n * sizeof(*scr->usage));
  return 0;
}

/* Logs a move of a pixel's match from centre (fx, fy) to (tx, ty). */
static int log_move(ts_pm_scratch *scr, uint32_t fx, uint32_t fy, uint32_t tx, uint32_t ty) {
  if (scr->nmoves + 4 > scr->cap) {
    size_t cap = scr->cap ? 2 * scr->cap : 4096;
    uint32_t *m = realloc(scr->moves, cap * sizeof(*m));
    if (m == NULL) return TS_ENOMEM;
    scr->moves = m;
    scr->cap = cap;
  }
  uint32_t *m = scr->moves + scr->nmoves;
  m[0] = fx, m[1] = fy, m[2] = tx, m[3] = ty;
  scr->nmoves += 4;
  return 0;
}

/* Applies (sign 1) or undoes (-1) a logged move. */
static void replay_move(const sweep *sw, const uint32_t *m, int32_t sign) {
  usage_move(sw, (int)m[0] - sw->r, (int)m[1] - sw->r, -sign);
  usage_move(sw, (int)m[2] - sw->r, (int)m[3] - sw->r, sign);
}

void ts_pm_scratch_free(ts_pm_scratch *scr) {
  free(scr->usage);
  free(scr->moves);
  free(scr->query);
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
  uint64_t d = distance(sw, x, y, (uint32_t)cx, (uint32_t)cy, j, b->d);
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

/* Resolves what tile sweeps of a pass read. */
static void sweep_init(sweep *sw, const ts_pm_pass *ps, ts_pm_scratch *scr) {
  int p = ps->patch, r = p / 2;
  *sw = (sweep){ps, p, r, ps->src->w - p + 1, ps->src->h - p + 1, ps->src->w - 1 - r, ps->src->h - 1 - r, ps->src->nparts, ps->scalar};
  for (int k = 0; k < sw->nparts; k++) {
    uint32_t ch = ps->src->ch[k];
    sw->part[k] = (part_geom){ps->src->part[k], ps->tgt->part[k], (size_t)ps->src->w * ch, (size_t)ps->tgt->w * ch, ch,
                              (uint32_t)p * ch, ((uint32_t)p * ch + 15) / 16, ps->win->spec.part[k].weight};
  }
  sw->usage = ps->k != 0 ? scr->usage : NULL;
  sw->k = ps->k;
  sw->query = scr->query;
  for (int i = 0; i < 2 * p - 1; i++) sw->tent[i] = (uint32_t)(p - (i < p ? p - 1 - i : i - (p - 1)));
}

uint64_t ts_pm_sweep_tile(const ts_pm_pass *ps, int t, ts_pm_scratch *scr, uint32_t *out, int *rc) {
  int ntx = (ps->tw + TS_PM_TILE - 1) / TS_PM_TILE;
  int x0 = (t % ntx) * TS_PM_TILE, y0 = (t / ntx) * TS_PM_TILE;
  int x1 = x0 + TS_PM_TILE < ps->tw ? x0 + TS_PM_TILE : ps->tw;
  int y1 = y0 + TS_PM_TILE < ps->th ? y0 + TS_PM_TILE : ps->th;
  *rc = 0;
  scr->nmoves = 0;
  sweep sw;
  sweep_init(&sw, ps, scr);
  ts_rng rng;
  ts_rng_seed(&rng, ps->seed, ((uint64_t)ps->pass << 32) | (uint32_t)t);
  int back = ps->pass & 1, step = back ? -1 : 1;
  uint64_t total = 0;
  for (int i = 0; i < y1 - y0 && *rc == 0; i++) {
    int y = back ? y1 - 1 - i : y0 + i;
    for (int jj = 0; jj < x1 - x0 && *rc == 0; jj++) {
      int x = back ? x1 - 1 - jj : x0 + jj;
      const uint32_t *cur = ps->in + 2 * ((size_t)y * (size_t)ps->tw + (size_t)x);
      best_t b = {0, cur[0], cur[1], patch_index(&sw, cur[0], cur[1])};
      query_load(&sw, x, y);
      b.d = distance(&sw, x, y, b.cx, b.cy, b.index, UINT64_MAX);
      uint32_t was = b.index, was_x = b.cx, was_y = b.cy;
      try_neighbour(&sw, out, x0, y0, x1, y1, x, y, x - step, y, &b);
      try_neighbour(&sw, out, x0, y0, x1, y1, x, y, x, y - step, &b);
      random_search(&sw, &rng, x, y, &b);
      uint32_t *o = out + 2 * ((size_t)y * (size_t)ps->tw + (size_t)x);
      o[0] = b.cx;
      o[1] = b.cy;
      total += b.d;
      if (sw.usage == NULL || b.index == was) continue;
      if ((*rc = log_move(scr, was_x, was_y, b.cx, b.cy)) == 0) replay_move(&sw, scr->moves + scr->nmoves - 4, 1);
    }
  }
  /* Undo the tile's moves: the usage is the pass's input again. */
  for (size_t m = 0; m < scr->nmoves; m += 4) replay_move(&sw, scr->moves + m, -1);
  return *rc == 0 ? total : 0;
}
