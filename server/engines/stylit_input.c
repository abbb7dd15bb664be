/* stylit_input.c - checking a stylization's parameters and inputs, and
 * turning the inputs into 8-bit planes (stylit.h says how and why). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "error.h"
#include "stylit_input.h"

/* ---- the check --------------------------------------------------------- */

typedef struct {
  char *msg;
  size_t len, used;
  int problems;
} problems;

/* One more problem, on a line of its own. */
static void problem(problems *pr, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void problem(problems *pr, const char *fmt, ...) {
  pr->problems++;
  if (pr->used + 2 >= pr->len) return;
  if (pr->used > 0) pr->msg[pr->used++] = '\n';
  va_list ap;
  va_start(ap, fmt);
  int n = vsnprintf(pr->msg + pr->used, pr->len - pr->used, fmt, ap);
  va_end(ap);
  if (n > 0) pr->used += (size_t)n < pr->len - pr->used ? (size_t)n : pr->len - pr->used - 1;
}

static int weight_ok(double w) { return w == 0.0 || (w >= 0.01 && w <= 100.0); }

static void check_params(const ts_stylit_params *p, problems *pr) {
  pr->msg[pr->used] = '\0';
  ts_params_check(ts_stylit_param_table, p, pr->msg, pr->len, &pr->problems);
  pr->used = strlen(pr->msg);
  if (!weight_ok(p->style_weight)) problem(pr, "--weight %g of the style: need 0 or 0.01..100", p->style_weight);
  double sum = p->style_weight;
  for (int k = 0; k < p->guides && k < TS_STYLIT_MAX_GUIDES; k++) {
    if (p->weight[k] >= 0 && !weight_ok(p->weight[k]))
      problem(pr, "--weight %g of guide %d: need 0 or 0.01..100", p->weight[k], k + 1);
    sum += ts_stylit_weight(p, k);
  }
  if (!(sum > 0)) problem(pr, "every weight is 0: nothing would be compared");
}

static int colour_channels(int channels) { return channels < 3 ? 1 : 3; }

/* Bytes of a part of n planes: its pixels, then zeros to the next chunk. */
static int part_bytes(int n, int patch) { return (n * patch * patch + TS_L1_CHUNK - 1) / TS_L1_CHUNK * TS_L1_CHUNK; }

/* Sizes and channels of the inputs: every mismatch, not just the first. */
static void check_inputs(const ts_stylit_params *p, const ts_image *const *in, problems *pr) {
  const ts_image *style = in[TS_STYLIT_IN_STYLE], *tgt0 = in[ts_stylit_in_tgt(0)];
  if (style->channels > TS_STYLIT_MAX_STYLE_CHANNELS)
    problem(pr, "the style has %d channels: need 1..%d", style->channels, TS_STYLIT_MAX_STYLE_CHANNELS);
  int planes = colour_channels(style->channels), bytes = part_bytes(planes, p->patch);
  for (int k = 0; k < p->guides; k++) {
    const ts_image *s = in[ts_stylit_in_src(k)], *t = in[ts_stylit_in_tgt(k)];
    if (s->width != style->width || s->height != style->height)
      problem(pr, "guide %d: its source is %dx%d, the style %dx%d (a source guide has the style's size)", k + 1,
              s->width, s->height, style->width, style->height);
    if (k > 0 && (t->width != tgt0->width || t->height != tgt0->height))
      problem(pr, "guide %d: its target is %dx%d, guide 1's %dx%d (every target guide has the output's size)", k + 1,
              t->width, t->height, tgt0->width, tgt0->height);
    if (s->channels != t->channels)
      problem(pr, "guide %d: its source has %d channels, its target %d", k + 1, s->channels, t->channels);
    if (s->channels > 4) problem(pr, "guide %d has %d channels: need 1..4", k + 1, s->channels);
    planes += colour_channels(s->channels);
    bytes += part_bytes(colour_channels(s->channels), p->patch);
  }
  if (planes > TS_WIN_MAX_PLANES)
    problem(pr, "the style and guides make %d channels to compare: at most %d", planes, TS_WIN_MAX_PLANES);
  else if (p->patch <= TS_STYLIT_MAX_PATCH && bytes > TS_L1_MAX_CHUNKS * TS_L1_CHUNK)
    problem(pr, "%dx%d patches of the style and guides make %d-byte vectors: at most %d; use a smaller "
            "--patch-size or fewer guides", p->patch, p->patch, bytes, TS_L1_MAX_CHUNKS * TS_L1_CHUNK);
}

/* The coarsest level must still hold a patch in the source and target. */
static void check_pyramid(const ts_stylit_params *p, const ts_image *const *in, problems *pr) {
  const ts_image *style = in[TS_STYLIT_IN_STYLE], *tgt = in[ts_stylit_in_tgt(0)];
  if ((uint64_t)tgt->width * (uint64_t)tgt->height > p->max_pixels)
    problem(pr, "the output would be %dx%d, over --max-pixels %llu", tgt->width, tgt->height,
            (unsigned long long)p->max_pixels);
  if (p->patch < 3 || p->patch > TS_STYLIT_MAX_PATCH || p->levels < 0 || p->levels > TS_STYLIT_MAX_LEVELS) return;
  int l = ts_stylit_levels(p, in) - 1;
  int sw = style->width >> l, sh = style->height >> l, tw = tgt->width >> l, th = tgt->height >> l;
  if (sw < p->patch || sh < p->patch || tw < 1 || th < 1)
    problem(pr,
            "--levels %d: the coarsest level's source is %dx%d and target %dx%d, and the source needs room for a "
            "%dx%d patch; use fewer levels or a smaller --patch-size",
            l + 1, sw, sh, tw, th, p->patch, p->patch);
  if (p->search == TS_STYLIT_LIST && p->nlevel_modes != l + 1)
    problem(pr, "--search lists %d level%s, the job runs %d: give one mode per level, coarsest first (or set --levels)",
            p->nlevel_modes, p->nlevel_modes == 1 ? "" : "s", l + 1);
}

int ts_stylit_check(const ts_stylit_params *p, const ts_image *const *in, char *msg, size_t len) {
  problems pr = {msg, len, 0, 0};
  msg[0] = '\0';
  if (p->guides < 1 || p->guides > TS_STYLIT_MAX_GUIDES) {
    problem(&pr, "%d guide pairs: need 1..%d --guide SRC TGT", p->guides, TS_STYLIT_MAX_GUIDES);
    return TS_EINVAL;
  }
  check_params(p, &pr);
  check_inputs(p, in, &pr);
  check_pyramid(p, in, &pr);
  return pr.problems ? TS_EINVAL : 0;
}

int ts_stylit_levels(const ts_stylit_params *p, const ts_image *const *in) {
  if (p->levels > 0) return p->levels;
  const ts_image *s = in[TS_STYLIT_IN_STYLE], *t = in[ts_stylit_in_tgt(0)];
  int side = 4 * p->patch, l = 1;
  while (l < 6 && (s->width >> l) >= side && (s->height >> l) >= side && (t->width >> l) >= side &&
         (t->height >> l) >= side)
    l++;
  return l;
}

/* ---- 8-bit planes ------------------------------------------------------ */

static int is_float(ts_pixtype t) { return t == TS_PIX_F16 || t == TS_PIX_F32; }

/* The finite range of channel c over both images of a pair. */
static void float_range(const ts_image *a, const ts_image *b, int c, float *lo, float *hi) {
  *lo = INFINITY;
  *hi = -INFINITY;
  const ts_image *img[2] = {a, b};
  for (int i = 0; i < 2; i++)
    for (int y = 0; y < img[i]->height; y++)
      for (int x = 0; x < img[i]->width; x++) {
        float v = ts_image_sample(img[i], x, y, c);
        if (!isfinite(v)) continue;
        if (v < *lo) *lo = v;
        if (v > *hi) *hi = v;
      }
  if (*lo > *hi) *lo = *hi = 0.0f;
}

/* Channel c of a float image stretched from [lo, hi] to 0..255. */
static void stretch(const ts_image *img, int c, float lo, float hi, uint8_t *out) {
  float scale = hi > lo ? 255.0f / (hi - lo) : 0.0f;
  for (int y = 0; y < img->height; y++)
    for (int x = 0; x < img->width; x++) {
      float v = ts_image_sample(img, x, y, c);
      float s = isnan(v) ? 0.0f : (v - lo) * scale;
      out[(size_t)y * (size_t)img->width + (size_t)x] = (uint8_t)(s <= 0.0f ? 0 : s >= 255.0f ? 255 : lrintf(s));
    }
}

/* The planes of guide k: the pair's colour channels, source and target. */
static int guide_planes(ts_stylit_planes *pl, const ts_image *s, const ts_image *t, int first, int n) {
  for (int c = 0; c < n; c++) {
    ts_plane *ps = &pl->src[first + c], *pt = &pl->tgt[first + c];
    if (ts_plane_alloc(ps, s->width, s->height) != 0 || ts_plane_alloc(pt, t->width, t->height) != 0)
      return TS_ENOMEM;
    if (is_float(s->type) || is_float(t->type)) {
      float lo, hi;
      float_range(s, t, c, &lo, &hi);
      stretch(s, c, lo, hi, ps->px);
      stretch(t, c, lo, hi, pt->px);
    } else {
      ts_image_channel8(s, c, ps->px);
      ts_image_channel8(t, c, pt->px);
    }
  }
  return 0;
}

int ts_stylit_planes_init(ts_stylit_planes *pl, const ts_stylit_params *p, const ts_image *const *in) {
  memset(pl, 0, sizeof(*pl));
  const ts_image *style = in[TS_STYLIT_IN_STYLE];
  pl->nstyle = colour_channels(style->channels);
  pl->nvote = style->channels;
  for (int c = 0; c < pl->nvote; c++) {
    if (ts_plane_alloc(&pl->vote[c], style->width, style->height) != 0) goto oom;
    ts_image_channel8(style, c, pl->vote[c].px);
  }
  for (int c = 0; c < pl->nstyle; c++) {
    if (ts_plane_alloc(&pl->src[c], style->width, style->height) != 0) goto oom;
    memcpy(pl->src[c].px, pl->vote[c].px, (size_t)style->width * (size_t)style->height);
  }
  pl->nplanes = pl->nstyle;
  for (int k = 0; k < p->guides; k++) {
    const ts_image *s = in[ts_stylit_in_src(k)], *t = in[ts_stylit_in_tgt(k)];
    pl->nguide[k] = colour_channels(s->channels);
    if (guide_planes(pl, s, t, pl->nplanes, pl->nguide[k]) != 0) goto oom;
    pl->nplanes += pl->nguide[k];
  }
  return 0;
oom:
  ts_stylit_planes_free(pl);
  return TS_ENOMEM;
}

void ts_stylit_planes_free(ts_stylit_planes *pl) {
  for (int i = 0; i < TS_WIN_MAX_PLANES; i++) {
    ts_plane_free(&pl->src[i]);
    ts_plane_free(&pl->tgt[i]);
  }
  for (int c = 0; c < TS_STYLIT_MAX_STYLE_CHANNELS; c++) ts_plane_free(&pl->vote[c]);
}
