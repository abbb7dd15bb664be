/* patchmatch.c - tile sweeps of the PatchMatch field (patchmatch.h). */
#include <stdalign.h>
#include <stddef.h>
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

#define AREA_PAD 3 /* zero overlap areas after each row; usage entries after the last */

/* ---- distance kernels -------------------------------------------------- */

/* Where part k of a patch lies: the packed planes of source and target and
 * their strides; with SSE2, how a patch row is cut into 16-byte chunks and
 * the mask of its last chunk's bytes. */
typedef struct {
  const uint8_t *src, *tgt;
  size_t src_row, tgt_row; /* bytes per image row */
  uint32_t ch, span;       /* bytes per pixel, per patch row */
  uint32_t nchunks;        /* 16-byte chunks per patch row */
  uint64_t weight;
  alignas(16) uint8_t tail[16];
} part_geom;

/* What a sweep reads, resolved once per tile. */
typedef struct {
  const ts_pm_pass *ps;
  int p, r, nx, ny; /* nx x ny source patches */
  int nparts;
  uint32_t *usage; /* U_j now (scratch): NULL without a penalty */
  uint64_t k;
  const uint32_t *area; /* overlap areas of two patches (scratch) */
  uint8_t *query;       /* SSE2: the target patch, chunked and masked */
  long radius[64];      /* the random search's: max(sw, sh) halved to 1 (an
                           int halves at most 31 times) */
  int nradii;
  part_geom part[TS_L1_MAX_PARTS];
} sweep;

/* A kernel: the weighted SAD of target pixel (x, y)'s patch and the source
 * patch with top-left pixel (sx, sy). Once the sum exceeds bound it may
 * stop: the value returned is then only known to exceed bound. Every kernel
 * returns the same value whenever it is within bound. */
typedef uint64_t patch_sad_fn(const sweep *sw, int x, int y, int sx, int sy, uint64_t bound);
/* Makes target pixel (x, y) the query of the kernels that read one. */
typedef void query_fn(sweep *sw, int x, int y);

static uint32_t sad_scalar(const uint8_t *a, const uint8_t *b, uint32_t n) {
  uint32_t s = 0;
  for (uint32_t i = 0; i < n; i++) s += (uint32_t)(a[i] > b[i] ? a[i] - b[i] : b[i] - a[i]);
  return s;
}

/* Plain loops on the planes: the reference the SIMD kernels must match. */
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

static void query_none(sweep *sw, int x, int y) { (void)sw, (void)x, (void)y; }

#ifdef __SSE2__
/* Copies target pixel (x, y)'s patch into sw->query, each part row as
 * nchunks 16-byte chunks with the bytes past the span zeroed: every
 * candidate of the pixel reads it. */
static void query_load_sse2(sweep *sw, int x, int y) {
  __m128i *q = (__m128i *)sw->query;
  for (int k = 0; k < sw->nparts; k++) {
    const part_geom *g = &sw->part[k];
    const uint8_t *t = g->tgt + (size_t)y * g->tgt_row + (size_t)x * g->ch;
    __m128i tail = _mm_load_si128((const __m128i *)g->tail);
    for (int row = 0; row < sw->p; row++, t += g->tgt_row) {
      uint32_t c = 0;
      for (; c + 1 < g->nchunks; c++) _mm_store_si128(q++, _mm_loadu_si128((const __m128i *)(t + 16 * c)));
      _mm_store_si128(q++, _mm_and_si128(_mm_loadu_si128((const __m128i *)(t + 16 * c)), tail));
    }
  }
}

/* The two 64-bit lanes of psadbw sums, added (each sum is below 2^32). */
static inline uint32_t lanes_sum(__m128i acc) {
  return (uint32_t)_mm_cvtsi128_si32(_mm_add_epi32(acc, _mm_unpackhi_epi64(acc, acc)));
}

/* Against the query: source bytes past a row's span are masked like the
 * query's, so they add 0. */
static uint64_t patch_sad_sse2(const sweep *sw, int x, int y, int sx, int sy, uint64_t bound) {
  (void)x, (void)y;
  const __m128i *q = (const __m128i *)sw->query;
  uint64_t d = 0;
  for (int k = 0; k < sw->nparts && d <= bound; k++) {
    const part_geom *g = &sw->part[k];
    const uint8_t *s = g->src + (size_t)sy * g->src_row + (size_t)sx * g->ch;
    __m128i tail = _mm_load_si128((const __m128i *)g->tail), acc = _mm_setzero_si128();
    for (int row = 0; row < sw->p; row++, s += g->src_row) {
      uint32_t c = 0;
      for (; c + 1 < g->nchunks; c++)
        acc = _mm_add_epi64(acc, _mm_sad_epu8(_mm_loadu_si128((const __m128i *)(s + 16 * c)), _mm_load_si128(q++)));
      __m128i last = _mm_and_si128(_mm_loadu_si128((const __m128i *)(s + 16 * c)), tail);
      acc = _mm_add_epi64(acc, _mm_sad_epu8(last, _mm_load_si128(q++)));
    }
    d += g->weight * lanes_sum(acc);
  }
  return d;
}

/* patch_sad_sse2 when every part row fits one chunk, for a patch side p
 * the compiler knows: the rows unrolled, no chunk loop. */
static inline __attribute__((always_inline)) uint64_t patch_sad_narrow(const sweep *sw, int sx, int sy, uint64_t bound,
                                                                       const int p) {
  const __m128i *q = (const __m128i *)sw->query;
  size_t px = (size_t)sy * (size_t)sw->ps->src->w + (size_t)sx;
  uint64_t d = 0;
  for (int k = 0; k < sw->nparts; k++, q += p) {
    const part_geom *g = &sw->part[k];
    const uint8_t *s = g->src + px * g->ch;
    __m128i tail = _mm_load_si128((const __m128i *)g->tail), acc = _mm_setzero_si128();
#pragma GCC unroll 8
    for (int row = 0; row < p; row++) {
      __m128i v = _mm_and_si128(_mm_loadu_si128((const __m128i *)(s + (size_t)row * g->src_row)), tail);
      acc = _mm_add_epi32(acc, _mm_sad_epu8(v, _mm_load_si128(q + row)));
    }
    d += g->weight * lanes_sum(acc);
    if (d > bound) break;
  }
  return d;
}

/* query_load_sse2 when every part row fits one chunk, patch side p known. */
static inline __attribute__((always_inline)) void query_load_narrow(sweep *sw, int x, int y, const int p) {
  __m128i *q = (__m128i *)sw->query;
  for (int k = 0; k < sw->nparts; k++, q += p) {
    const part_geom *g = &sw->part[k];
    const uint8_t *t = g->tgt + (size_t)y * g->tgt_row + (size_t)x * g->ch;
    __m128i tail = _mm_load_si128((const __m128i *)g->tail);
#pragma GCC unroll 8
    for (int row = 0; row < p; row++)
      _mm_store_si128(q + row, _mm_and_si128(_mm_loadu_si128((const __m128i *)(t + (size_t)row * g->tgt_row)), tail));
  }
}

static inline __attribute__((always_inline)) void query_load_narrow3(sweep *sw, int x, int y) {
  query_load_narrow(sw, x, y, 3);
}

static inline __attribute__((always_inline)) void query_load_narrow5(sweep *sw, int x, int y) {
  query_load_narrow(sw, x, y, 5);
}

static inline __attribute__((always_inline)) uint64_t patch_sad_narrow3(const sweep *sw, int x, int y, int sx, int sy,
                                                                        uint64_t bound) {
  (void)x, (void)y;
  return patch_sad_narrow(sw, sx, sy, bound, 3);
}

static inline __attribute__((always_inline)) uint64_t patch_sad_narrow5(const sweep *sw, int x, int y, int sx, int sy,
                                                                        uint64_t bound) {
  (void)x, (void)y;
  return patch_sad_narrow(sw, sx, sy, bound, 5);
}
#endif

/* Bytes of the SSE2 query of a window with patch p. */
static size_t query_bytes(const ts_pm_image *src, int p) {
  size_t n = 0;
  for (int k = 0; k < src->nparts; k++) n += (size_t)p * (((size_t)p * src->ch[k] + 15) / 16) * 16;
  return n;
}

/* ---- occurrences ------------------------------------------------------- */

/* Each centre counts once at its patch's top-left pixel; a p-wide box sum
 * along the rows, then along the columns, spreads the counts over the
 * patches: p - 1 additions a pixel each way, not p * p per field entry.
 * Both sums run against the direction of their reach (from the right,
 * from the bottom), so each reads only entries not yet overwritten. */
void ts_pm_occurrences(const uint32_t *field, size_t n, int p, int sw, int sh, uint32_t *counts) {
  int r = p / 2;
  memset(counts, 0, (size_t)sw * (size_t)sh * sizeof(*counts));
  for (size_t i = 0; i < n; i++)
    counts[((size_t)field[2 * i + 1] - (size_t)r) * (size_t)sw + field[2 * i] - (size_t)r]++;
  for (int y = 0; y < sh; y++) {
    uint32_t *row = counts + (size_t)y * (size_t)sw, sum = 0; /* row[x] becomes row[x - p + 1 .. x]'s sum */
    for (int x = sw - p > 0 ? sw - p : 0; x < sw; x++) sum += row[x];
    for (int x = sw - 1; x >= 0; x--) {
      uint32_t own = row[x];
      row[x] = sum;
      sum -= own;
      if (x >= p) sum += row[x - p];
    }
  }
  for (int y = sh - 1; y > 0; y--) {
    uint32_t *row = counts + (size_t)y * (size_t)sw;
    for (int k = 1; k < p && k <= y; k++) {
      const uint32_t *above = row - (size_t)k * (size_t)sw;
      for (int x = 0; x < sw; x++) row[x] += above[x];
    }
  }
}

void ts_pm_block_sums(const uint32_t *counts, int p, int sw, int sh, uint32_t *col, uint32_t *ublock) {
  int nx = sw - p + 1;
  memset(col, 0, (size_t)sw * sizeof(*col)); /* column sums over p rows */
  for (int y = 0; y < p - 1; y++)
    for (int x = 0; x < sw; x++) col[x] += counts[(size_t)y * (size_t)sw + (size_t)x];
  for (int y = 0; y + p <= sh; y++) {
    const uint32_t *in = counts + (size_t)(y + p - 1) * (size_t)sw;
    for (int x = 0; x < sw; x++) col[x] += in[x];
    if (y > 0) { /* the row leaving the window */
      const uint32_t *out = in - (size_t)p * (size_t)sw;
      for (int x = 0; x < sw; x++) col[x] -= out[x];
    }
    uint32_t *u = ublock + (size_t)y * (size_t)nx, s = 0;
    for (int x = 0; x < p - 1; x++) s += col[x];
    for (int x = 0; x < nx; x++) {
      s += col[x + p - 1];
      u[x] = s;
      s -= col[x];
    }
  }
}

/* ---- the tile's own moves ---------------------------------------------- */

/* row[i] += a[i] for n entries, or -= a[i] when neg is all ones ((a ^ neg)
 * - neg is a or -a). padded: a row of areas that runs to its end, so in
 * fours the up to 3 entries past n add its zero padding (AREA_PAD). */
static inline __attribute__((always_inline)) void add_row(uint32_t *restrict row, const uint32_t *restrict a, int n,
                                                          uint32_t neg, int padded) {
  int i = 0;
#ifdef __SSE2__
  __m128i m = _mm_set1_epi32((int)neg);
#pragma GCC unroll 4
  for (; padded && i < n; i += 4) {
    __m128i v = _mm_sub_epi32(_mm_xor_si128(_mm_loadu_si128((const __m128i *)(a + i)), m), m);
    _mm_storeu_si128((__m128i *)(row + i), _mm_add_epi32(_mm_loadu_si128((const __m128i *)(row + i)), v));
  }
#else
  (void)padded;
#endif
  for (; i < n; i++) row[i] += (a[i] ^ neg) - neg;
}

/* U_j of every source patch overlapping the one at anchor (ax, ay) grows
 * (sign 1) or shrinks (-1) by the overlap's area. Unsigned arithmetic
 * wraps, so a move and its undoing cancel exactly. */
static void usage_move(const sweep *sw, int ax, int ay, int sign) {
  int p = sw->p, reach = p - 1, stride = 2 * p - 1 + AREA_PAD;
  int x0 = ax > reach ? ax - reach : 0, x1 = ax + p < sw->nx ? ax + p : sw->nx;
  int y0 = ay > reach ? ay - reach : 0, y1 = ay + p < sw->ny ? ay + p : sw->ny;
  uint32_t neg = sign > 0 ? 0 : UINT32_MAX;
  int padded = x1 == ax + p; /* not cut by the right edge */
  for (int y = y0; y < y1; y++)
    add_row(sw->usage + (size_t)y * (size_t)sw->nx + (size_t)x0,
            sw->area + (size_t)(y - ay + reach) * (size_t)stride + (size_t)(x0 - ax + reach), x1 - x0, neg, padded);
}

/* Grows *buf to n elements of size bytes (contents lost): 0 or TS_ENOMEM. */
static int buffer_reserve(void **buf, size_t *cap, size_t n, size_t size) {
  if (n <= *cap) return 0;
  free(*buf);
  *buf = aligned_alloc(16, (n * size + 15) / 16 * 16);
  *cap = *buf != NULL ? n : 0;
  return *buf != NULL ? 0 : TS_ENOMEM;
}

int ts_pm_scratch_begin(ts_pm_scratch *scr, const ts_pm_pass *ps) {
  int p = ps->patch, side = 2 * p - 1, stride = side + AREA_PAD;
  size_t npatches = (size_t)(ps->src->w - p + 1) * (size_t)(ps->src->h - p + 1);
  if (buffer_reserve((void **)&scr->query, &scr->query_cap, query_bytes(ps->src, p), 1) != 0) return TS_ENOMEM;
  if (ps->k == 0) return 0;
  if (buffer_reserve((void **)&scr->usage, &scr->usage_cap, npatches + AREA_PAD, sizeof(*scr->usage)) != 0 ||
      buffer_reserve((void **)&scr->area, &scr->area_cap, (size_t)side * (size_t)stride, sizeof(*scr->area)) != 0)
    return TS_ENOMEM;
  memcpy(scr->usage, ps->ublock, npatches * sizeof(*scr->usage));
  for (int dy = 0; dy < side; dy++)
    for (int dx = 0; dx < stride; dx++)
      scr->area[dy * stride + dx] = dx < side ? (uint32_t)((p - abs(dy - (p - 1))) * (p - abs(dx - (p - 1)))) : 0;
  return 0;
}

/* Logs a move of a pixel's match from anchor (fx, fy) to (tx, ty). */
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

/* usage_move with a patch side p the compiler knows (0: sw->p, unknown):
 * a patch clear of the edges takes its rows unrolled. */
static inline __attribute__((always_inline)) void usage_move_fixed(const sweep *sw, int ax, int ay, int sign,
                                                                   const int p) {
  if (p == 0 || ax < p - 1 || ay < p - 1 || ax + p > sw->nx || ay + p > sw->ny) {
    usage_move(sw, ax, ay, sign);
    return;
  }
  uint32_t neg = sign > 0 ? 0 : UINT32_MAX;
  uint32_t *row = sw->usage + (size_t)(ay - (p - 1)) * (size_t)sw->nx + (size_t)(ax - (p - 1));
  const uint32_t *a = sw->area;
#pragma GCC unroll 16
  for (int y = 0; y < 2 * p - 1; y++, row += sw->nx, a += 2 * p - 1 + AREA_PAD) add_row(row, a, 2 * p - 1, neg, 1);
}

/* Applies (sign 1) or undoes (-1) a logged move; p as usage_move_fixed's. */
static inline __attribute__((always_inline)) void replay_move_fixed(const sweep *sw, const uint32_t *m, int sign,
                                                                    const int p) {
  usage_move_fixed(sw, (int)m[0], (int)m[1], -sign, p);
  usage_move_fixed(sw, (int)m[2], (int)m[3], sign, p);
}

/* The replays a sweep calls: never inlined, as they would crowd the
 * registers of the sweep's loop (which then runs slower). */
typedef void replay_fn(const sweep *sw, const uint32_t *m, int sign);
static __attribute__((noinline)) void replay_any(const sweep *sw, const uint32_t *m, int sign) {
  replay_move_fixed(sw, m, sign, 0);
}
#ifdef __SSE2__ /* those of the narrow kernels */
static __attribute__((noinline)) void replay_p3(const sweep *sw, const uint32_t *m, int sign) {
  replay_move_fixed(sw, m, sign, 3);
}
static __attribute__((noinline)) void replay_p5(const sweep *sw, const uint32_t *m, int sign) {
  replay_move_fixed(sw, m, sign, 5);
}
#endif

void ts_pm_scratch_free(ts_pm_scratch *scr) {
  free(scr->usage);
  free(scr->moves);
  free(scr->query);
  free(scr->area);
  memset(scr, 0, sizeof(*scr));
}

/* ---- the sweep --------------------------------------------------------- */

int ts_pm_tiles(int tw, int th) {
  return ((tw + TS_PM_TILE - 1) / TS_PM_TILE) * ((th + TS_PM_TILE - 1) / TS_PM_TILE);
}

/* The best source patch of a pixel so far. The sweep works on patches'
 * anchors (top-left pixels, centre - r), the field holds their centres. */
typedef struct {
  uint64_t d;
  uint32_t ax, ay, index;
} best_t;

/* Index of the source patch anchored at (ax, ay). */
static inline uint32_t patch_index(const sweep *sw, uint32_t ax, uint32_t ay) {
  return ay * (uint32_t)sw->nx + ax;
}

/* Distance of target pixel (x, y) to source patch j anchored at (ax, ay),
 * as the kernel's: exact within bound. The penalty comes last, so a
 * candidate the patch alone rules out never reads the usage. */
static inline __attribute__((always_inline)) uint64_t distance(const sweep *sw, patch_sad_fn *sad, int x, int y,
                                                               uint32_t ax, uint32_t ay, uint32_t j, uint64_t bound) {
  uint64_t d = sad(sw, x, y, (int)ax, (int)ay, bound);
  if (sw->usage != NULL && d <= bound) d += ts_usage_penalty(sw->usage[j], sw->k);
  return d;
}

/* Keeps the patch anchored at (ax, ay) when strictly better: a smaller
 * distance, or an equal one at a lower index. */
static inline __attribute__((always_inline)) void try_patch(const sweep *sw, patch_sad_fn *sad, int x, int y,
                                                            uint32_t ax, uint32_t ay, best_t *b) {
  uint32_t j = patch_index(sw, ax, ay);
  if (j == b->index) return;
  uint64_t d = distance(sw, sad, x, y, ax, ay, j, b->d);
  if (d < b->d || (d == b->d && j < b->index)) *b = (best_t){d, ax, ay, j};
}

/* v clamped to [0, hi] without a branch: at the wide radii either side is a
 * coin toss, which a branch would mispredict half the time. */
static inline long clamp_to(long v, long hi) {
  v &= -(long)(v > 0);
  return v < hi ? v : hi;
}

/* Where a sweep stands: the tile, its direction, the fields. */
typedef struct {
  int x0, y0, x1, y1;
  int back;
  const uint32_t *in;
  uint32_t *out;
} tile_pos;

/* The match of neighbour (nbx, nby) of (x, y), shifted by the step back to
 * (x, y): from this pass when it lies in the tile, else from the input. */
static inline __attribute__((always_inline)) void try_neighbour(const sweep *sw, patch_sad_fn *sad, const tile_pos *tp,
                                                                int x, int y, int nbx, int nby, best_t *b) {
  const ts_pm_pass *ps = sw->ps;
  if (nbx < 0 || nby < 0 || nbx >= ps->tw || nby >= ps->th) return;
  int inside = nbx >= tp->x0 && nbx < tp->x1 && nby >= tp->y0 && nby < tp->y1;
  const uint32_t *f = (inside ? tp->out : tp->in) + 2 * ((size_t)nby * (size_t)ps->tw + (size_t)nbx);
  long ax = (long)f[0] - sw->r + (x - nbx), ay = (long)f[1] - sw->r + (y - nby);
  if (ax < 0 || ay < 0 || ax >= sw->nx || ay >= sw->ny) return;
  try_patch(sw, sad, x, y, (uint32_t)ax, (uint32_t)ay, b);
}

static inline __attribute__((always_inline)) void random_search(const sweep *sw, patch_sad_fn *sad, ts_rng *rng, int x,
                                                                int y, best_t *b) {
  for (int i = 0; i < sw->nradii; i++) {
    long radius = sw->radius[i];
    long ax = (long)b->ax + (long)ts_rng_below(rng, (uint32_t)(2 * radius + 1)) - radius;
    long ay = (long)b->ay + (long)ts_rng_below(rng, (uint32_t)(2 * radius + 1)) - radius;
    try_patch(sw, sad, x, y, (uint32_t)clamp_to(ax, sw->nx - 1), (uint32_t)clamp_to(ay, sw->ny - 1), b);
  }
}

/* Resolves what tile sweeps of a pass read. */
static void sweep_init(sweep *sw, const ts_pm_pass *ps, const ts_pm_scratch *scr) {
  int p = ps->patch, r = p / 2;
  memset(sw, 0, offsetof(sweep, part));
  sw->ps = ps;
  sw->p = p;
  sw->r = r;
  sw->nx = ps->src->w - p + 1;
  sw->ny = ps->src->h - p + 1;
  sw->nparts = ps->src->nparts;
  for (int k = 0; k < sw->nparts; k++) {
    part_geom *g = &sw->part[k];
    g->ch = ps->src->ch[k];
    g->src = ps->src->part[k];
    g->tgt = ps->tgt->part[k];
    g->src_row = (size_t)ps->src->w * g->ch;
    g->tgt_row = (size_t)ps->tgt->w * g->ch;
    g->span = (uint32_t)p * g->ch;
    g->nchunks = (g->span + 15) / 16;
    g->weight = ps->win->spec.part[k].weight;
    uint32_t last = g->span - 16 * (g->nchunks - 1);
    for (uint32_t i = 0; i < 16; i++) g->tail[i] = i < last ? 0xFF : 0;
  }
  sw->usage = ps->k != 0 ? scr->usage : NULL;
  sw->k = ps->k;
  sw->area = scr->area;
  sw->query = scr->query;
  for (long radius = ps->src->w > ps->src->h ? ps->src->w : ps->src->h; radius >= 1; radius /= 2)
    sw->radius[sw->nradii++] = radius;
}

/* The tile's pixels in sweep order, each trying its own match, its two
 * neighbours' and the random candidates, then the tile's moves undone (the
 * usage is the pass's input again): the sweep with one kernel, which the
 * compiler inlines, and one replay of moves. */
static inline __attribute__((always_inline)) uint64_t sweep_pixels(sweep *sw, const tile_pos *tp, ts_pm_scratch *scr,
                                                                   ts_rng *stream, query_fn *load, patch_sad_fn *sad,
                                                                   replay_fn *replay, int *rc) {
  const ts_pm_pass *ps = sw->ps;
  int step = tp->back ? -1 : 1;
  uint64_t total = 0;
  ts_rng rng_copy = *stream, *rng = &rng_copy; /* a local the compiler keeps in registers */
  for (int i = 0; i < tp->y1 - tp->y0 && *rc == 0; i++) {
    int y = tp->back ? tp->y1 - 1 - i : tp->y0 + i;
    for (int jj = 0; jj < tp->x1 - tp->x0 && *rc == 0; jj++) {
      int x = tp->back ? tp->x1 - 1 - jj : tp->x0 + jj;
      size_t at = 2 * ((size_t)y * (size_t)ps->tw + (size_t)x);
      best_t b = {0, tp->in[at] - (uint32_t)sw->r, tp->in[at + 1] - (uint32_t)sw->r, 0};
      b.index = patch_index(sw, b.ax, b.ay);
      load(sw, x, y);
      b.d = distance(sw, sad, x, y, b.ax, b.ay, b.index, UINT64_MAX);
      best_t was = b;
      try_neighbour(sw, sad, tp, x, y, x - step, y, &b);
      try_neighbour(sw, sad, tp, x, y, x, y - step, &b);
      random_search(sw, sad, rng, x, y, &b);
      tp->out[at] = b.ax + (uint32_t)sw->r;
      tp->out[at + 1] = b.ay + (uint32_t)sw->r;
      total += b.d;
      if (sw->usage == NULL || b.index == was.index) continue;
      if ((*rc = log_move(scr, was.ax, was.ay, b.ax, b.ay)) == 0) replay(sw, scr->moves + scr->nmoves - 4, 1);
    }
  }
  for (size_t m = 0; m < scr->nmoves; m += 4) replay(sw, scr->moves + m, -1);
  *stream = rng_copy;
  return total;
}

#define SWEEP_WITH(name, load, sad, replay)                                                       \
  static uint64_t name(sweep *sw, const tile_pos *tp, ts_pm_scratch *scr, ts_rng *rng, int *rc) { \
    return sweep_pixels(sw, tp, scr, rng, load, sad, replay, rc);                                 \
  }
SWEEP_WITH(sweep_scalar, query_none, patch_sad_scalar, replay_any)
#ifdef __SSE2__
SWEEP_WITH(sweep_sse2, query_load_sse2, patch_sad_sse2, replay_any)
SWEEP_WITH(sweep_narrow3, query_load_narrow3, patch_sad_narrow3, replay_p3)
SWEEP_WITH(sweep_narrow5, query_load_narrow5, patch_sad_narrow5, replay_p5)
#endif

typedef uint64_t sweep_fn(sweep *sw, const tile_pos *tp, ts_pm_scratch *scr, ts_rng *rng, int *rc);

/* The sweep of the pass's variant: scalar, or SSE2 with the rows unrolled
 * for patches 3 and 5 when each part row fits a chunk. */
static sweep_fn *sweep_variant(const sweep *sw) {
#ifdef __SSE2__
  if (sw->ps->scalar) return sweep_scalar;
  int narrow = 1;
  for (int k = 0; k < sw->nparts; k++) narrow &= sw->part[k].nchunks == 1;
  if (narrow && sw->p == 3) return sweep_narrow3;
  if (narrow && sw->p == 5) return sweep_narrow5;
  return sweep_sse2;
#else
  (void)sw;
  return sweep_scalar;
#endif
}

uint64_t ts_pm_sweep_tile(const ts_pm_pass *ps, int t, ts_pm_scratch *scr, uint32_t *out, int *rc) {
  int ntx = (ps->tw + TS_PM_TILE - 1) / TS_PM_TILE;
  tile_pos tp = {(t % ntx) * TS_PM_TILE, (t / ntx) * TS_PM_TILE, 0, 0, (int)(ps->pass & 1), ps->in, out};
  tp.x1 = tp.x0 + TS_PM_TILE < ps->tw ? tp.x0 + TS_PM_TILE : ps->tw;
  tp.y1 = tp.y0 + TS_PM_TILE < ps->th ? tp.y0 + TS_PM_TILE : ps->th;
  *rc = 0;
  scr->nmoves = 0;
  sweep sw;
  sweep_init(&sw, ps, scr);
  ts_rng rng;
  ts_rng_seed(&rng, ps->seed, ((uint64_t)ps->pass << 32) | (uint32_t)t);
  uint64_t total = sweep_variant(&sw)(&sw, &tp, scr, &rng, rc);
  return *rc == 0 ? total : 0;
}
