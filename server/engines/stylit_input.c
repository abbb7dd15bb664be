/* stylit_input.c - checking a stylization's parameters and inputs, and
 * turning the inputs into 8-bit planes (stylit.h says how and why). */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "error.h"
#include "stylit_input.h"
#include "util.h"

void ts_stylit_params_default(ts_stylit_params *p) {
  memset(p, 0, sizeof(*p));
  p->patch = 5;
  p->iters = 6;
  p->uniformity = 1.0;
  p->seed = 1;
  p->max_pixels = TS_IMAGE_DEFAULT_MAX_PIXELS;
  p->guides = 1;
  p->style_weight = 1.0;
  for (int k = 0; k < TS_STYLIT_MAX_GUIDES; k++) p->weight[k] = -1.0;
  p->search = TS_STYLIT_SIZE;
  p->pm_iters = 4;
  p->budget = 1.0;
}

static const char *const kSearchNames[] = {"exact", "patchmatch", "auto", "size"};

const char *ts_stylit_search_name(int mode) {
  return mode >= TS_STYLIT_EXACT && mode <= TS_STYLIT_SIZE ? kSearchNames[mode] : "unknown";
}

static int mode_of(const char *name, size_t len, int last) {
  for (int m = TS_STYLIT_EXACT; m <= last; m++)
    if (strlen(kSearchNames[m]) == len && strncmp(name, kSearchNames[m], len) == 0) return m;
  return -1;
}

int ts_stylit_search_parse(const char *text, ts_stylit_params *p, char *err) {
  int m = mode_of(text, strlen(text), TS_STYLIT_SIZE);
  if (m >= 0) {
    p->search = m;
    p->nlevel_modes = 0;
    return 0;
  }
  int n = 0;
  for (const char *s = text;; n++) {
    const char *comma = strchr(s, ',');
    size_t len = comma != NULL ? (size_t)(comma - s) : strlen(s);
    int lm = n < TS_STYLIT_MAX_LEVELS ? mode_of(s, len, TS_STYLIT_PATCHMATCH) : -1;
    if (lm < 0)
      return ts_error(err, TS_EINVAL, "--search %s: need exact, patchmatch, size, auto, or a list of exact and patchmatch "
                      "with one per level, coarsest first (at most %d)", text, TS_STYLIT_MAX_LEVELS);
    p->level_mode[n] = (uint8_t)lm;
    if (comma == NULL) break;
    s = comma + 1;
  }
  p->search = TS_STYLIT_LIST;
  p->nlevel_modes = n + 1;
  return 0;
}

void ts_stylit_search_format(const ts_stylit_params *p, char *out, size_t cap) {
  if (p->search != TS_STYLIT_LIST) {
    snprintf(out, cap, "%s", ts_stylit_search_name(p->search));
    return;
  }
  size_t o = 0;
  out[0] = '\0';
  for (int l = 0; l < p->nlevel_modes && o < cap; l++) {
    int n = snprintf(out + o, cap - o, "%s%s", l ? "," : "", ts_stylit_search_name(p->level_mode[l]));
    o += n > 0 ? (size_t)n : 0;
  }
}

double ts_stylit_weight(const ts_stylit_params *p, int k) {
  return p->weight[k] < 0 ? 1.0 / p->guides : p->weight[k];
}

/* ---- the check --------------------------------------------------------- */

static int weight_ok(double w) { return w == 0.0 || (w >= 0.01 && w <= 100.0); }

static void check_params(const ts_stylit_params *p, ts_problems *pr) {
  if (p->patch < 3 || p->patch > TS_STYLIT_MAX_PATCH || p->patch % 2 == 0)
    ts_problems_add(pr, "--patch-size %d: need an odd number in 3..%d", p->patch, TS_STYLIT_MAX_PATCH);
  if (p->levels < 0 || p->levels > TS_STYLIT_MAX_LEVELS)
    ts_problems_add(pr, "--levels %d: need 1..%d (or 0: as many as fit)", p->levels, TS_STYLIT_MAX_LEVELS);
  if (p->iters < 1 || p->iters > 100) ts_problems_add(pr, "--iters %d: need 1..100", p->iters);
  if (p->search < TS_STYLIT_EXACT || p->search > TS_STYLIT_LIST) ts_problems_add(pr, "search mode %d: need exact, patchmatch, size or auto", p->search);
  if (p->pm_iters < 1 || p->pm_iters > 100) ts_problems_add(pr, "--pm-iters %d: need 1..100", p->pm_iters);
  if (!(p->budget >= 0 && p->budget <= 1e6)) ts_problems_add(pr, "--budget %g: need 0..1000000 seconds", p->budget);
  if (!(p->uniformity >= 0.0 && p->uniformity <= 1000.0))
    ts_problems_add(pr, "--uniformity %g: need 0..1000 (0: off)", p->uniformity);
  if (!weight_ok(p->style_weight)) ts_problems_add(pr, "--weight %g of the style: need 0 or 0.01..100", p->style_weight);
  double sum = p->style_weight;
  for (int k = 0; k < p->guides && k < TS_STYLIT_MAX_GUIDES; k++) {
    if (p->weight[k] >= 0 && !weight_ok(p->weight[k]))
      ts_problems_add(pr, "--weight %g of guide %d: need 0 or 0.01..100", p->weight[k], k + 1);
    sum += ts_stylit_weight(p, k);
  }
  if (!(sum > 0)) ts_problems_add(pr, "every weight is 0: nothing would be compared");
}

static int colour_channels(int channels) { return channels < 3 ? 1 : 3; }

/* Bytes of a part of n planes: its pixels, then zeros to the next chunk. */
static int part_bytes(int n, int patch) { return (n * patch * patch + TS_L1_CHUNK - 1) / TS_L1_CHUNK * TS_L1_CHUNK; }

/* Sizes and channels of the inputs: every mismatch, not just the first. */
static void check_inputs(const ts_stylit_params *p, const ts_image *const *in, ts_problems *pr) {
  const ts_image *style = in[TS_STYLIT_IN_STYLE], *tgt0 = in[ts_stylit_in_tgt(0)];
  if (style->channels > TS_STYLIT_MAX_STYLE_CHANNELS)
    ts_problems_add(pr, "the style has %d channels: need 1..%d", style->channels, TS_STYLIT_MAX_STYLE_CHANNELS);
  int planes = colour_channels(style->channels), bytes = part_bytes(planes, p->patch);
  for (int k = 0; k < p->guides; k++) {
    const ts_image *s = in[ts_stylit_in_src(k)], *t = in[ts_stylit_in_tgt(k)];
    if (s->width != style->width || s->height != style->height)
      ts_problems_add(pr, "guide %d: its source is %dx%d, the style %dx%d (a source guide has the style's size)", k + 1,
              s->width, s->height, style->width, style->height);
    if (k > 0 && (t->width != tgt0->width || t->height != tgt0->height))
      ts_problems_add(pr, "guide %d: its target is %dx%d, guide 1's %dx%d (every target guide has the output's size)", k + 1,
              t->width, t->height, tgt0->width, tgt0->height);
    if (s->channels != t->channels)
      ts_problems_add(pr, "guide %d: its source has %d channels, its target %d", k + 1, s->channels, t->channels);
    if (s->channels > 4) ts_problems_add(pr, "guide %d has %d channels: need 1..4", k + 1, s->channels);
    planes += colour_channels(s->channels);
    bytes += part_bytes(colour_channels(s->channels), p->patch);
  }
  if (planes > TS_WIN_MAX_PLANES)
    ts_problems_add(pr, "the style and guides make %d channels to compare: at most %d", planes, TS_WIN_MAX_PLANES);
  else if (p->patch <= TS_STYLIT_MAX_PATCH && bytes > TS_L1_MAX_CHUNKS * TS_L1_CHUNK)
    ts_problems_add(pr, "%dx%d patches of the style and guides make %d-byte vectors: at most %d; use a smaller "
            "--patch-size or fewer guides", p->patch, p->patch, bytes, TS_L1_MAX_CHUNKS * TS_L1_CHUNK);
}

/* The coarsest level must still hold a patch in the source and target. */
static void check_pyramid(const ts_stylit_params *p, const ts_image *const *in, ts_problems *pr) {
  const ts_image *style = in[TS_STYLIT_IN_STYLE], *tgt = in[ts_stylit_in_tgt(0)];
  if ((uint64_t)tgt->width * (uint64_t)tgt->height > p->max_pixels)
    ts_problems_add(pr, "the output would be %dx%d, over --max-pixels %llu", tgt->width, tgt->height,
            (unsigned long long)p->max_pixels);
  if (p->patch < 3 || p->patch > TS_STYLIT_MAX_PATCH || p->levels < 0 || p->levels > TS_STYLIT_MAX_LEVELS) return;
  int l = ts_stylit_levels(p, in) - 1;
  int sw = style->width >> l, sh = style->height >> l, tw = tgt->width >> l, th = tgt->height >> l;
  if (sw < p->patch || sh < p->patch || tw < 1 || th < 1)
    ts_problems_add(pr,
            "--levels %d: the coarsest level's source is %dx%d and target %dx%d, and the source needs room for a "
            "%dx%d patch; use fewer levels or a smaller --patch-size",
            l + 1, sw, sh, tw, th, p->patch, p->patch);
  if (p->search == TS_STYLIT_LIST && p->nlevel_modes != l + 1)
    ts_problems_add(pr, "--search lists %d level%s, the job runs %d: give one mode per level, coarsest first (or set --levels)",
            p->nlevel_modes, p->nlevel_modes == 1 ? "" : "s", l + 1);
}

int ts_stylit_check(const ts_stylit_params *p, const ts_image *const *in, char *msg, size_t len) {
  ts_problems pr = {msg, len, 0};
  msg[0] = '\0';
  if (p->guides < 1 || p->guides > TS_STYLIT_MAX_GUIDES) {
    ts_problems_add(&pr, "%d guide pairs: need 1..%d --guide SRC TGT", p->guides, TS_STYLIT_MAX_GUIDES);
    return TS_EINVAL;
  }
  check_params(p, &pr);
  check_inputs(p, in, &pr);
  check_pyramid(p, in, &pr);
  return pr.count ? TS_EINVAL : 0;
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
