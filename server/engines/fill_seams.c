/* fill_seams.c - see fill_seams.h.
 *
 * One seam: the pixel pairs across the edge u0 (between u0 - 1 and u0 on
 * the axis across the seam, u) along a run of rows (v) where the pairs are
 * of one class, one of them a work pixel, and their copies do not continue
 * each other. The band is the `reach` pixels on either side; a state k in
 * -reach..reach is where the row's join goes: k < 0 gives the pixels
 * [u0 + k, u0) the copy of u0 gone on backwards, k > 0 the pixels
 * [u0, u0 + k) that of u0 - 1 gone on forwards, 0 leaves the row. A state
 * is allowed when every pixel it changes may take that copy. The cost of a
 * row's state is that of its pairs across the seam and, between rows, of
 * the pairs along it; the least total over the run is found by dynamic
 * programming, ties to the state nearest 0 (the row as it was), then to
 * the negative one. */
#include "fill_seams.h"

#include <stddef.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"

#define BAND (2 * TS_SEAM_MAX_REACH + 2) /* the band's columns and one outside each side */
#define STATES (2 * TS_SEAM_MAX_REACH + 1)
#define NO_COST INT64_MAX

/* The directions a copy may go on in: across the seam forwards and
 * backwards, along it forwards and backwards (a pair's cost reads the
 * first pixel's copy forwards and the second's backwards). */
enum { FWD_U, BACK_U, FWD_V, BACK_V };

/* A pixel's copy: its class, where in the class's reference, the rows of
 * its source there, its values, and the values of its copy gone on by one
 * pixel in each direction (its own where the copy would leave its
 * source); exists = 0 outside the image. */
typedef struct {
  uint8_t exists, cls;
  int sx, sy, ylo, yhi;
  uint8_t v[TS_MAX_PLANES];
  uint8_t next[4][TS_MAX_PLANES];
} cand;

/* A row of a seam: per band column (u = u0 - reach - 1 + j) the pixel as
 * it is and the other side's copy gone on (alt_ok: it may take it). */
typedef struct {
  cand cur[BAND], alt[BAND];
  uint8_t alt_ok[BAND];
} seam_row;

/* The pair costs a row's states are made of, per label (0 the pixel as it
 * is, 1 the other copy) of each pixel: across the seam, pair (j - 1, j);
 * along it, column j to the row before in the run; and to the fixed rows
 * just before and after the run (the first and last rows only). */
typedef struct {
  uint32_t across[BAND][2][2], along[BAND][2][2], before[BAND][2], after[BAND][2];
} row_costs;

typedef struct {
  ts_seam_image *im;
  int U, V;           /* the image's size across and along the seams */
  int ax, ay, bx, by; /* one pixel across, one along, in (x, y) */
  int dir[4][2];      /* FWD_U .. BACK_V in (x, y) */
  int reach, nstates;
  int order[STATES];          /* states by preference: 0, -1, 1, -2, 2, ... */
  uint8_t take[STATES][BAND]; /* state k (at k + reach) gives column j the other copy */
  uint8_t cols[STATES][BAND]; /* those columns, ncols of them */
  int ncols[STATES];
  seam_row *rows;             /* the run's */
  uint8_t *back;              /* per row of the run and state: the best state before */
  uint64_t moved;
} cutter;

static size_t idx(const cutter *c, int u, int v) {
  return c->ax ? (size_t)v * (size_t)c->im->w + (size_t)u : (size_t)u * (size_t)c->im->w + (size_t)v;
}

static void source_rows(const ts_seam_ref *r, int y, int *lo, int *hi) {
  int s = 0;
  while (s + 1 < r->nsrc && y >= r->y0[s + 1]) s++;
  *lo = r->y0[s];
  *hi = r->y0[s] + r->h0[s];
}

/* The values of p's copy gone on by (dx, dy), into v: 1, or 0 where it
 * would leave its source. */
static int go_on(const ts_seam_image *im, const cand *p, int dx, int dy, uint8_t *v) {
  if (p->cls == 0) return 0;
  const ts_seam_ref *r = &im->ref[p->cls - 1];
  int x = p->sx + dx, y = p->sy + dy;
  if (x < 0 || x >= r->w || y < p->ylo || y >= p->yhi) return 0;
  size_t o = (size_t)y * (size_t)r->w + (size_t)x;
  for (int k = 0; k < im->nplanes; k++) v[k] = r->planes[k][o];
  return 1;
}

/* p's copy gone on in the directions of `dirs` (bits 1 << FWD_U ...,
 * c->dir in (x, y)). */
#define ALL_DIRS 15u
static void cand_next(const cutter *c, cand *p, unsigned dirs) {
  const ts_seam_image *im = c->im;
  if (p->cls == 0) {
    for (int k = 0; k < 4; k++) memcpy(p->next[k], p->v, sizeof(p->v));
    return;
  }
  const ts_seam_ref *r = &im->ref[p->cls - 1];
  size_t o = (size_t)p->sy * (size_t)r->w + (size_t)p->sx;
  for (int k = 0; k < 4; k++) {
    if (!(dirs >> k & 1)) continue;
    int x = p->sx + c->dir[k][0], y = p->sy + c->dir[k][1];
    if (x < 0 || x >= r->w || y < p->ylo || y >= p->yhi) {
      memcpy(p->next[k], p->v, sizeof(p->v));
      continue;
    }
    ptrdiff_t d = (ptrdiff_t)c->dir[k][1] * r->w + c->dir[k][0];
    for (int q = 0; q < im->nplanes; q++) p->next[k][q] = r->planes[q][(ptrdiff_t)o + d];
  }
}

static void cand_pixel(const cutter *c, int u, int v, cand *p, unsigned dirs) {
  const ts_seam_image *im = c->im;
  p->exists = u >= 0 && u < c->U && v >= 0 && v < c->V;
  if (!p->exists) return;
  size_t i = idx(c, u, v);
  p->cls = im->cls[i];
  for (int k = 0; k < im->nplanes; k++) p->v[k] = im->planes[k][i];
  if (p->cls != 0) {
    p->sx = (int)im->copy[2 * i];
    p->sy = (int)im->copy[2 * i + 1];
    source_rows(&im->ref[p->cls - 1], p->sy, &p->ylo, &p->yhi);
  }
  cand_next(c, p, dirs);
}

/* The cost of neighbours a and b, b the next pixel from a in direction
 * fwd (FWD_U or FWD_V): how far each one's copy gone on is from the
 * other; 0 where the two copies continue each other. */
static uint32_t pair_cost(const ts_seam_image *im, const cand *a, const cand *b, int fwd) {
  if (!a->exists || !b->exists) return 0;
  uint32_t d = 0;
  for (int k = 0; k < im->nplanes; k++)
    d += (uint32_t)abs((int)a->next[fwd][k] - (int)b->v[k]) + (uint32_t)abs((int)b->next[fwd + 1][k] - (int)a->v[k]);
  return d;
}

/* Pixels (u0 - 1, v) and (u0, v) make a seam row. */
static int is_seam(const cutter *c, int u0, int v) {
  const ts_seam_image *im = c->im;
  size_t a = idx(c, u0 - 1, v), b = idx(c, u0, v);
  if (im->cls[a] == 0 || im->cls[a] != im->cls[b] || !(im->movable[a] || im->movable[b])) return 0;
  return im->copy[2 * b] != im->copy[2 * a] + (uint32_t)c->ax || im->copy[2 * b + 1] != im->copy[2 * a + 1] + (uint32_t)c->ay;
}

/* Row v of the seam at u0: the pixels and the copies they may take. */
static void build_row(const cutter *c, int u0, int v, seam_row *r) {
  const ts_seam_image *im = c->im;
  int n = 2 * c->reach + 2;
  for (int j = 0; j < n; j++) /* the columns outside the band meet it across the seam only */
    cand_pixel(c, u0 - c->reach - 1 + j, v, &r->cur[j], j == 0 ? 1u << FWD_U : j == n - 1 ? 1u << BACK_U : ALL_DIRS);
  const cand *left = &r->cur[c->reach], *right = &r->cur[c->reach + 1]; /* u0 - 1 and u0 */
  for (int j = 0; j < n; j++) {
    int u = u0 - c->reach - 1 + j;
    r->alt_ok[j] = 0;
    if (j == 0 || j == n - 1 || !r->cur[j].exists || !im->movable[idx(c, u, v)]) continue;
    const cand *e = u < u0 ? right : left;
    int s = u < u0 ? u - u0 : u - u0 + 1;
    cand *a = &r->alt[j];
    *a = *e;
    if (e->cls != r->cur[j].cls || !go_on(im, e, s * c->ax, s * c->ay, a->v)) continue;
    a->sx = e->sx + s * c->ax;
    a->sy = e->sy + s * c->ay;
    const ts_seam_ref *ref = &im->ref[e->cls - 1];
    r->alt_ok[j] = ref->usable == NULL || ref->usable[(size_t)a->sy * (size_t)ref->w + (size_t)a->sx];
    if (r->alt_ok[j]) cand_next(c, a, ALL_DIRS);
  }
}

static int allowed(const cutter *c, const seam_row *r, int k) {
  for (int j = 1; j <= 2 * c->reach; j++)
    if (c->take[k + c->reach][j] && !r->alt_ok[j]) return 0;
  return 1;
}

static const cand *as(const seam_row *r, int j, int l) { return l ? &r->alt[j] : &r->cur[j]; }

/* Row r's pair costs (r is row v of the seam at u0; prev the row before
 * in the run, or NULL); first, last: r begins, ends the run. */
static void costs_of(const cutter *c, int u0, int v, const seam_row *r, const seam_row *prev, int first, int last,
                     row_costs *rc) {
  const ts_seam_image *im = c->im;
  int n = 2 * c->reach + 1;
  for (int j = 1; j <= n; j++)
    for (int la = 0; la <= r->alt_ok[j - 1]; la++)
      for (int lb = 0; lb <= r->alt_ok[j]; lb++) rc->across[j][la][lb] = pair_cost(im, as(r, j - 1, la), as(r, j, lb), FWD_U);
  for (int j = 1; j < n; j++) {
    for (int la = 0; prev != NULL && la <= prev->alt_ok[j]; la++)
      for (int lb = 0; lb <= r->alt_ok[j]; lb++) rc->along[j][la][lb] = pair_cost(im, as(prev, j, la), as(r, j, lb), FWD_V);
    rc->before[j][0] = rc->before[j][1] = rc->after[j][0] = rc->after[j][1] = 0;
    cand o;
    if (first && v > 0) {
      cand_pixel(c, u0 - c->reach - 1 + j, v - 1, &o, 1u << FWD_V);
      for (int l = 0; l <= r->alt_ok[j]; l++) rc->before[j][l] = pair_cost(im, &o, as(r, j, l), FWD_V);
    }
    if (last && v + 1 < c->V) {
      cand_pixel(c, u0 - c->reach - 1 + j, v + 1, &o, 1u << BACK_V);
      for (int l = 0; l <= r->alt_ok[j]; l++) rc->after[j][l] = pair_cost(im, as(r, j, l), &o, FWD_V);
    }
  }
}

/* The row's own cost in state k: its pairs across the seam, and along it
 * to the fixed rows before and after the run. */
static uint64_t row_cost(const cutter *c, const row_costs *rc, int k) {
  const uint8_t *t = c->take[k + c->reach];
  uint64_t s = 0;
  for (int j = 1; j <= 2 * c->reach + 1; j++) s += rc->across[j][t[j - 1]][t[j]];
  for (int j = 1; j <= 2 * c->reach; j++) s += rc->before[j][t[j]] + rc->after[j][t[j]];
  return s;
}

/* The pairs along the seam between the row before in state k and this one
 * in state kn, less those of both rows as they are (the same for every
 * pair of states, so the choice is unchanged): only the columns either
 * state changes count. */
static int64_t step_cost(const cutter *c, const row_costs *rc, int k, int kn) {
  const uint8_t *t = c->take[k + c->reach], *tn = c->take[kn + c->reach];
  int64_t s = 0;
  for (int i = 0; i < c->ncols[k + c->reach]; i++) {
    int j = c->cols[k + c->reach][i];
    s += (int64_t)rc->along[j][1][tn[j]] - rc->along[j][0][0];
  }
  for (int i = 0; i < c->ncols[kn + c->reach]; i++) {
    int j = c->cols[kn + c->reach][i];
    if (!t[j]) s += (int64_t)rc->along[j][0][1] - rc->along[j][0][0];
  }
  return s;
}

static void apply(cutter *c, const seam_row *r, int k, int u0, int v) {
  ts_seam_image *im = c->im;
  for (int j = 1; j <= 2 * c->reach; j++) {
    if (!c->take[k + c->reach][j]) continue;
    size_t i = idx(c, u0 - c->reach - 1 + j, v);
    const cand *a = &r->alt[j];
    im->copy[2 * i] = (uint32_t)a->sx;
    im->copy[2 * i + 1] = (uint32_t)a->sy;
    for (int p = 0; p < im->nplanes; p++) im->planes[p][i] = a->v[p];
    c->moved++;
  }
}

/* The run of seam rows [va, vb) at u0. */
static void cut_run(cutter *c, int u0, int va, int vb) {
  int n = vb - va, ns = c->nstates, R = c->reach;
  int64_t cost[STATES], next[STATES];
  row_costs rc;
  for (int i = 0; i < n; i++) build_row(c, u0, va + i, &c->rows[i]);
  costs_of(c, u0, va, &c->rows[0], NULL, 1, n == 1, &rc);
  for (int k = -R; k <= R; k++) cost[k + R] = allowed(c, &c->rows[0], k) ? (int64_t)row_cost(c, &rc, k) : NO_COST;
  for (int i = 1; i < n; i++) {
    const seam_row *q = &c->rows[i];
    costs_of(c, u0, va + i, q, &c->rows[i - 1], 0, i == n - 1, &rc);
    for (int kn = -R; kn <= R; kn++) {
      next[kn + R] = NO_COST;
      if (!allowed(c, q, kn)) continue;
      int64_t own = (int64_t)row_cost(c, &rc, kn);
      for (int t = 0; t < ns; t++) {
        int k = c->order[t];
        if (cost[k + R] == NO_COST) continue;
        int64_t total = cost[k + R] + step_cost(c, &rc, k, kn) + own;
        if (total < next[kn + R]) {
          next[kn + R] = total;
          c->back[(size_t)i * STATES + (size_t)(kn + R)] = (uint8_t)(k + R);
        }
      }
    }
    memcpy(cost, next, sizeof(cost));
  }
  int k = 0; /* state 0 is always allowed */
  for (int t = 0; t < ns; t++)
    if (cost[c->order[t] + R] < cost[k + R]) k = c->order[t];
  for (int i = n - 1; i >= 0; i--) {
    apply(c, &c->rows[i], k, u0, va + i);
    if (i > 0) k = (int)c->back[(size_t)i * STATES + (size_t)(k + R)] - R;
  }
}

/* Every seam across the u axis, edge by edge, run by run. */
static void cut_all(cutter *c) {
  for (int u0 = 1; u0 < c->U; u0++)
    for (int v = 0; v < c->V;) {
      if (!is_seam(c, u0, v)) {
        v++;
        continue;
      }
      int vb = v + 1;
      while (vb < c->V && is_seam(c, u0, vb)) vb++;
      cut_run(c, u0, v, vb);
      v = vb;
    }
}

int ts_fill_cut_seams(ts_seam_image *im, uint64_t *moved) {
  *moved = 0;
  if (im->reach < 1) return 0;
  int longest = im->w > im->h ? im->w : im->h;
  cutter c = {.im = im, .reach = im->reach < TS_SEAM_MAX_REACH ? im->reach : TS_SEAM_MAX_REACH};
  c.nstates = 2 * c.reach + 1;
  for (int t = 0, k = 0; t < c.nstates; k++) {
    c.order[t++] = -k;
    if (k > 0) c.order[t++] = k;
  }
  for (int k = -c.reach; k <= c.reach; k++)
    for (int j = 0; j < BAND; j++) {
      int d = j - c.reach - 1; /* u - u0 */
      c.take[k + c.reach][j] = (uint8_t)((k < 0 && d >= k && d < 0) || (k > 0 && d >= 0 && d < k));
      if (c.take[k + c.reach][j]) c.cols[k + c.reach][c.ncols[k + c.reach]++] = (uint8_t)j;
    }
  c.rows = malloc(sizeof(seam_row) * (size_t)longest);
  c.back = malloc((size_t)longest * STATES);
  if (c.rows == NULL || c.back == NULL) {
    free(c.rows);
    free(c.back);
    return TS_ENOMEM;
  }
  for (int dir = 0; dir < 2; dir++) { /* vertical seams (across x), then horizontal */
    c.ax = dir == 0;
    c.ay = dir == 1;
    c.bx = c.ay;
    c.by = c.ax;
    const int d[4][2] = {{c.ax, c.ay}, {-c.ax, -c.ay}, {c.bx, c.by}, {-c.bx, -c.by}};
    memcpy(c.dir, d, sizeof(d));
    c.U = dir == 0 ? im->w : im->h;
    c.V = dir == 0 ? im->h : im->w;
    cut_all(&c);
  }
  free(c.rows);
  free(c.back);
  *moved = c.moved;
  return 0;
}
