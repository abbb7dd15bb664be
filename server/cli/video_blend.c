/* video_blend.c - see video_blend.h.
 *
 * Between two keys K1 < K2 every frame t has two stylizations: F_t, from
 * K1 forward, and B_t, from K2 backward, each with the error its chain
 * piled up along the flow (video_chain.h: each frame's error map, the
 * stylize job's patch distances, added to the previous frame's pile
 * warped onto t). After Jamriška et al. ("Stylizing Video by Example",
 * SIGGRAPH 2019) the two are merged per pixel by that error, then blended
 * so that the switch from one to the other shows neither as a seam in the
 * frame nor as a jump in time.
 *
 * Selection. d = pile(F) - pile(B), averaged over a box of radius
 * max(2, min(w, h) / 24) so that the choice is made per region, never per
 * pixel (no salt and pepper). A pixel B took stays B: the previous
 * frame's selection is warped along F's flow, so the choice moves with the
 * content, and never flips back (no flicker between the chains). Then B's
 * share grows to the frame's place, (t - K1) / (K2 - K1): the pixels that
 * change over are those not yet B where d is greatest, where F has piled
 * up the most error against B. Why a schedule, not a threshold on d: the
 * piles grow by about a frame's error a frame, so a threshold moves almost
 * every region over within a frame or two of the middle, and a whole
 * frame's strokes changing at once is the step the blend must not show
 * (measured: 1.6x the median step on a 10-frame shot, 1.1x with the
 * schedule; bench/video_blend.py). One 3x3 majority pass trims what the
 * warp frays. Just after K1 every pixel holds F (the frame before is the
 * key, F's own).
 *
 * Blending: gradient-domain, a screened Poisson equation per channel:
 * the image u whose differences between 4-neighbours are the selected
 * chain's (across a seam, the mean of both chains' differences) and whose
 * colours stay close to the linear blend L = (F (K2 - t) + B (t - K1)) /
 * (K2 - K1):  minimise  sum_edges ((u_p - u_q) - g_pq)^2 + LAMBDA sum_p
 * (u_p - L_p)^2. Why this and not histogram-preserving blending: the
 * painting's strokes, its high frequencies, come from one chain only
 * (no ghost, no double strokes, which a mix of two stroke patterns shows
 * however its histogram is corrected), the seam vanishes (its jump is
 * spread over the screening length 1 / sqrt(LAMBDA), about 4.5 pixels),
 * and the low frequencies follow L, which moves smoothly from K1's colours
 * to K2's: no step in time where a region switches. Histogram-preserving
 * blending keeps the stroke statistics of a linear mix but not its
 * strokes, and still cross-fades two stroke patterns.
 *
 * Solved by conjugate gradients from the hard composite, CG_ITERS
 * iterations whatever the residual, in doubles in one fixed order (and
 * -std=c11 keeps the compiler from contracting into FMAs): the same bytes
 * on every run and machine. The blend runs in the CLI after the chains,
 * whose files are the same embedded and on any pool. */
#include "video_blend.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "flow.h"
#include "image.h"

#define SMOOTH_DIV 24
#define LAMBDA 0.05
#define CG_ITERS 64

typedef struct {
  const ts_video *v;
  const char *dir;
  int w, h, ch;
  size_t n;
  uint8_t *f, *b;        /* F_t and B_t, interleaved */
  float *af, *ab, *flow; /* the piles, F's flow from t to t - 1 */
  double *sat;           /* the summed-area table of pile(F) - pile(B) */
  float *mask, *warped;  /* the selection as floats (1: B), for the warp */
  uint8_t *sel, *maj;    /* the selection, 1: B */
  uint32_t *order;       /* pixels not yet B, by their difference */
  double *x, *r, *p, *ap, *rhs;
} blender;

/* The keys around frame t: *lo the last key at or before it (-1: none),
 * *hi the first at or after it (nkeys: none). */
static void keys_around(const ts_video *v, long t, int *lo, int *hi) {
  *lo = -1;
  *hi = v->nkeys;
  for (int k = 0; k < v->nkeys; k++) {
    if (v->key[k].frame <= t) *lo = k;
    if (v->key[k].frame >= t && *hi == v->nkeys) *hi = k;
  }
}

static int blender_alloc(blender *bl, const ts_video *v, const char *dir, char *err) {
  *bl = (blender){.v = v, .dir = dir, .w = v->w, .h = v->h, .ch = v->channels, .n = (size_t)v->w * (size_t)v->h};
  size_t n = bl->n;
  bl->f = malloc(n * bl->ch);
  bl->b = malloc(n * bl->ch);
  bl->af = malloc(sizeof(float) * n);
  bl->ab = malloc(sizeof(float) * n);
  bl->flow = malloc(sizeof(float) * 2 * n);
  bl->sat = malloc(sizeof(double) * (size_t)(v->w + 1) * (size_t)(v->h + 1));
  bl->mask = malloc(sizeof(float) * n);
  bl->warped = malloc(sizeof(float) * n);
  bl->sel = malloc(n);
  bl->maj = malloc(n);
  bl->order = malloc(sizeof(uint32_t) * n);
  bl->x = malloc(sizeof(double) * n);
  bl->r = malloc(sizeof(double) * n);
  bl->p = malloc(sizeof(double) * n);
  bl->ap = malloc(sizeof(double) * n);
  bl->rhs = malloc(sizeof(double) * n);
  int ok = bl->f && bl->b && bl->af && bl->ab && bl->flow && bl->sat && bl->mask && bl->warped && bl->sel &&
           bl->maj && bl->order && bl->x && bl->r && bl->p && bl->ap && bl->rhs;
  return ok ? 0 : ts_error(err, TS_ENOMEM, "out of memory for the blend of %dx%d frames", v->w, v->h);
}

static void blender_free(blender *bl) {
  void *all[] = {bl->f, bl->b, bl->af, bl->ab, bl->flow, bl->sat, bl->mask, bl->warped, bl->sel, bl->maj,
                 bl->order, bl->x, bl->r, bl->p, bl->ap, bl->rhs};
  for (size_t i = 0; i < sizeof(all) / sizeof(all[0]); i++) free(all[i]);
}

/* ---- selection ----------------------------------------------------------- */

/* The summed-area table of pile(F) - pile(B), in doubles. */
static void difference_table(blender *bl) {
  int w = bl->w, sw = w + 1;
  memset(bl->sat, 0, sizeof(double) * (size_t)sw);
  for (int y = 0; y < bl->h; y++) {
    double row = 0;
    bl->sat[(size_t)(y + 1) * sw] = 0;
    for (int x = 0; x < w; x++) {
      size_t i = (size_t)y * w + x;
      row += (double)bl->af[i] - (double)bl->ab[i];
      bl->sat[(size_t)(y + 1) * sw + x + 1] = bl->sat[(size_t)y * sw + x + 1] + row;
    }
  }
}

/* The mean of the difference over the box of radius rad around (x, y),
 * clipped to the frame. */
static double box_mean(const blender *bl, int x, int y, int rad) {
  int x0 = x - rad < 0 ? 0 : x - rad, y0 = y - rad < 0 ? 0 : y - rad;
  int x1 = x + rad + 1 > bl->w ? bl->w : x + rad + 1, y1 = y + rad + 1 > bl->h ? bl->h : y + rad + 1;
  size_t sw = (size_t)bl->w + 1;
  double s = bl->sat[y1 * sw + x1] - bl->sat[y0 * sw + x1] - bl->sat[y1 * sw + x0] + bl->sat[y0 * sw + x0];
  return s / ((double)(x1 - x0) * (y1 - y0));
}

/* Orders pixel indices by their smoothed difference d, greatest first,
 * ties by index: a total order, so the same selection everywhere. */
static int by_difference(const void *a, const void *b, void *ctx) {
  const double *d = ctx;
  uint32_t i = *(const uint32_t *)a, j = *(const uint32_t *)b;
  if (d[i] != d[j]) return d[i] > d[j] ? -1 : 1;
  return i < j ? -1 : i > j;
}

/* The selection of frame t (share: B's share by the frame's place) from
 * the piles and the previous frame's selection (bl->mask, warped here
 * along F's flow); B's share of the result. */
static double select_chains(blender *bl, double share) {
  int w = bl->w, h = bl->h, side = w < h ? w : h, rad = side / SMOOTH_DIV > 2 ? side / SMOOTH_DIV : 2;
  difference_table(bl);
  ts_flow_warp(bl->mask, w, h, 1, bl->flow, bl->warped);
  size_t had = 0, open = 0;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      size_t i = (size_t)y * w + x;
      bl->x[i] = box_mean(bl, x, y, rad);
      bl->sel[i] = bl->warped[i] >= 0.5f;
      had += bl->sel[i];
      if (!bl->sel[i]) bl->order[open++] = (uint32_t)i;
    }
  size_t want = (size_t)ceil(share * (double)bl->n), more = want > had ? want - had : 0;
  qsort_r(bl->order, open, sizeof(uint32_t), by_difference, bl->x);
  for (size_t k = 0; k < more && k < open; k++) bl->sel[bl->order[k]] = 1;
  size_t taken = 0;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      int ones = 0, all = 0;
      for (int yy = y - 1; yy <= y + 1; yy++)
        for (int xx = x - 1; xx <= x + 1; xx++)
          if (xx >= 0 && yy >= 0 && xx < w && yy < h) {
            ones += bl->sel[(size_t)yy * w + xx];
            all++;
          }
      size_t i = (size_t)y * w + x;
      bl->maj[i] = 2 * ones > all;
      taken += bl->maj[i];
    }
  for (size_t i = 0; i < bl->n; i++) bl->mask[i] = bl->maj[i];
  return (double)taken / (double)bl->n;
}

/* ---- the screened Poisson blend ----------------------------------------- */

/* The sample of channel c at pixel i of the chain the pixel selects. */
static double chosen(const blender *bl, size_t i, int c) {
  return bl->maj[i] ? bl->b[i * bl->ch + c] : bl->f[i * bl->ch + c];
}

/* g for the edge i-j: the selected chain's u_i - u_j; across a seam the
 * mean of both chains'. */
static double guide(const blender *bl, size_t i, size_t j, int c) {
  if (bl->maj[i] == bl->maj[j]) return chosen(bl, i, c) - chosen(bl, j, c);
  int ch = bl->ch;
  return 0.5 * (((double)bl->f[i * ch + c] - bl->f[j * ch + c]) + ((double)bl->b[i * ch + c] - bl->b[j * ch + c]));
}

/* out = A u: (LAMBDA + neighbours) u_p - the sum of the neighbours' u. */
static void apply(const blender *bl, const double *u, double *out) {
  int w = bl->w, h = bl->h;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      size_t i = (size_t)y * w + x;
      double s = LAMBDA * u[i];
      if (x > 0) s += u[i] - u[i - 1];
      if (x + 1 < w) s += u[i] - u[i + 1];
      if (y > 0) s += u[i] - u[i - w];
      if (y + 1 < h) s += u[i] - u[i + w];
      out[i] = s;
    }
}

static double dot(const double *a, const double *b, size_t n) {
  double s = 0;
  for (size_t i = 0; i < n; i++) s += a[i] * b[i];
  return s;
}

/* The right-hand side of channel c for frame t of K1..K2, and the start:
 * the hard composite. */
static void poisson_setup(blender *bl, int c, long t, long k1, long k2) {
  int w = bl->w, h = bl->h, ch = bl->ch;
  double span = (double)(k2 - k1);
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      size_t i = (size_t)y * w + x;
      double lin = (bl->f[i * ch + c] * (double)(k2 - t) + bl->b[i * ch + c] * (double)(t - k1)) / span;
      double s = LAMBDA * lin;
      if (x > 0) s += guide(bl, i, i - 1, c);
      if (x + 1 < w) s += guide(bl, i, i + 1, c);
      if (y > 0) s += guide(bl, i, i - w, c);
      if (y + 1 < h) s += guide(bl, i, i + w, c);
      bl->rhs[i] = s;
      bl->x[i] = chosen(bl, i, c);
    }
}

/* Conjugate gradients, CG_ITERS iterations (fewer only if the residual is
 * exactly 0), then channel c of out rounded. */
static void poisson_solve(blender *bl, int c, uint8_t *out) {
  size_t n = bl->n;
  apply(bl, bl->x, bl->ap);
  for (size_t i = 0; i < n; i++) bl->p[i] = bl->r[i] = bl->rhs[i] - bl->ap[i];
  double rr = dot(bl->r, bl->r, n);
  for (int it = 0; it < CG_ITERS && rr > 0; it++) {
    apply(bl, bl->p, bl->ap);
    double alpha = rr / dot(bl->p, bl->ap, n);
    for (size_t i = 0; i < n; i++) {
      bl->x[i] += alpha * bl->p[i];
      bl->r[i] -= alpha * bl->ap[i];
    }
    double rr2 = dot(bl->r, bl->r, n), beta = rr2 / rr;
    for (size_t i = 0; i < n; i++) bl->p[i] = bl->r[i] + beta * bl->p[i];
    rr = rr2;
  }
  for (size_t i = 0; i < n; i++) {
    double u = floor(bl->x[i] + 0.5);
    out[i * bl->ch + c] = (uint8_t)(u < 0 ? 0 : u > 255 ? 255 : u);
  }
}

/* ---- the frames ----------------------------------------------------------- */

/* Frame t between keys k1 < k2 into out: read, selected, blended; the
 * share of B into *share. */
static int blend_frame(blender *bl, long t, long k1, long k2, uint8_t *out, double *share, char *err) {
  char path[TS_VIDEO_PATH];
  ts_video_chain_file(bl->dir, k1, t, "out.png", path, sizeof(path));
  int rc = ts_video_read8(bl->v, path, bl->f, err);
  ts_video_chain_file(bl->dir, k2, t, "out.png", path, sizeof(path));
  if (rc == 0) rc = ts_video_read8(bl->v, path, bl->b, err);
  ts_video_chain_file(bl->dir, k1, t, "acc.raw", path, sizeof(path));
  if (rc == 0) rc = ts_video_read_floats(path, bl->af, bl->n, err);
  ts_video_chain_file(bl->dir, k2, t, "acc.raw", path, sizeof(path));
  if (rc == 0) rc = ts_video_read_floats(path, bl->ab, bl->n, err);
  ts_video_chain_file(bl->dir, k1, t, "flow.raw", path, sizeof(path));
  if (rc == 0) rc = ts_video_read_floats(path, bl->flow, 2 * bl->n, err);
  if (rc != 0) return rc;
  if (t == k1 + 1) memset(bl->mask, 0, sizeof(float) * bl->n); /* the frame before is K1's own: F */
  *share = select_chains(bl, (double)(t - k1) / (double)(k2 - k1));
  for (int c = 0; c < bl->ch; c++) {
    poisson_setup(bl, c, t, k1, k2);
    poisson_solve(bl, c, out);
  }
  return 0;
}

/* Output frame t into px: one chain's, or the two blended. */
static int frame_out(blender *bl, long t, uint8_t *px, ts_video_blend *b, char *err) {
  const ts_video *v = bl->v;
  int lo, hi;
  keys_around(v, t, &lo, &hi);
  long k1 = lo >= 0 ? v->key[lo].frame : -1, k2 = hi < v->nkeys ? v->key[hi].frame : -1;
  if (lo >= 0 && hi < v->nkeys && k1 != k2) {
    b->frame[b->nframes] = t;
    return blend_frame(bl, t, k1, k2, px, &b->backward[b->nframes++], err);
  }
  char path[TS_VIDEO_PATH];
  ts_video_chain_file(bl->dir, lo >= 0 ? k1 : k2, t, "out.png", path, sizeof(path));
  return ts_video_read8(v, path, px, err);
}

int ts_video_blend_write(const ts_video *v, const char *dir, ts_video_blend *b, char *err) {
  size_t frames = (size_t)(v->fr.last - v->fr.first + 1);
  *b = (ts_video_blend){0, malloc(sizeof(long) * frames), malloc(sizeof(double) * frames)};
  blender bl;
  int rc = blender_alloc(&bl, v, dir, err);
  uint8_t *px = rc == 0 ? malloc(bl.n * bl.ch) : NULL;
  if (rc == 0 && (px == NULL || b->frame == NULL || b->backward == NULL)) rc = ts_error(err, TS_ENOMEM, "out of memory");
  char path[TS_VIDEO_PATH];
  for (long t = v->fr.first; rc == 0 && t <= v->fr.last; t++) {
    rc = frame_out(&bl, t, px, b, err);
    ts_image img = {v->w, v->h, v->channels, TS_PIX_U8, px, NULL};
    ts_frame_path(v->out, t, path, sizeof(path)); /* fits: checked */
    if (rc == 0) rc = ts_image_write(path, &img, NULL, err);
  }
  free(px);
  blender_free(&bl);
  return rc;
}

void ts_video_blend_free(ts_video_blend *b) {
  free(b->frame);
  free(b->backward);
  *b = (ts_video_blend){0};
}

void ts_video_blend_json(FILE *f, const ts_video_blend *b) {
  fprintf(f, "{\"method\": \"screened Poisson\", \"selection\": \"accumulated error, ranked; backward share by "
          "place\", \"smoothing\": \"1/%d of the shorter side\", \"lambda\": %g, \"iterations\": %d, \"frames\": [",
          SMOOTH_DIV, LAMBDA, CG_ITERS);
  for (long i = 0; i < b->nframes; i++)
    fprintf(f, "%s{\"frame\": %ld, \"backward\": %.4f}", i ? ", " : "", b->frame[i], b->backward[i]);
  fprintf(f, "]}");
}
