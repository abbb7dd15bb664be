/* segment_input.c - a segmentation's parameters and inputs: their checks
 * (every problem at once, each naming its input), the classes of the label
 * rasters, and the 8-bit planes the search compares (segment.h). */
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "param.h"
#include "segment.h"
#include "util.h"

#define F(field) offsetof(ts_seg_params, field)

/* In the spec's order. pairs and truth follow from the inputs given. */
const ts_param ts_seg_param_table[] = {
    {"pairs", NULL, NULL, TS_PARAM_INT, F(pairs), 1, TS_SEG_MAX_PAIRS, "1", "training pairs"},
    {"levels", "levels", "L", TS_PARAM_INT, F(levels), 1, TS_SEG_MAX_LEVELS, "3",
     "pyramid levels, 1 = the single level"},
    {"window", "window", "N", TS_PARAM_INT, F(window), 3, TS_SEG_MAX_WINDOW, "9", "window width",
     .flags = TS_PARAM_ODD},
    {"denoise", "denoise", "MIN_AREA", TS_PARAM_INT, F(denoise), 0, TS_SEG_MAX_DENOISE, "0",
     "regions (4-connected) of fewer pixels take the class most of their border touches; 0 = off"},
    {"rgb_search", "rgb-search", NULL, TS_PARAM_FLAG, F(rgb), 0, 1, "0",
     "compare the three colour channels instead of luminance"},
    {"truth", NULL, NULL, TS_PARAM_FLAG, F(truth), 0, 1, "0", "the last input is a truth raster"},
    {"max_pixels", NULL, NULL, TS_PARAM_U64, F(max_pixels), 0, 0, "268435456", "input size limit",
     .flags = TS_PARAM_UNBOUNDED},
    {NULL}};

void ts_seg_params_default(ts_seg_params *p) {
  memset(p, 0, sizeof(*p));
  ts_params_default(ts_seg_param_table, p);
}

static int pairs_of(const ts_seg_params *p) {
  return p->pairs < 1 ? 0 : p->pairs > TS_SEG_MAX_PAIRS ? TS_SEG_MAX_PAIRS : p->pairs;
}

int ts_seg_ninputs(const ts_seg_params *p) { return 1 + 2 * pairs_of(p) + (p->truth ? 1 : 0); }

void ts_seg_role_names(const ts_seg_params *p, char (*names)[TS_SEG_NAME_LEN]) {
  snprintf(names[TS_SEG_IN_INPUT], TS_SEG_NAME_LEN, "--input");
  for (int k = 0; k < pairs_of(p); k++) {
    snprintf(names[ts_seg_in_train(k)], TS_SEG_NAME_LEN, "--train #%d", k + 1);
    snprintf(names[ts_seg_in_labels(k)], TS_SEG_NAME_LEN, "--labels #%d", k + 1);
  }
  if (p->truth) snprintf(names[1 + 2 * pairs_of(p)], TS_SEG_NAME_LEN, "--truth");
}

/* ---- problems ------------------------------------------------------------ */

typedef struct {
  char *msg;
  size_t len, used;
  int count;
} problems;

/* One more problem, on a line of its own. */
static void problem(problems *pr, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void problem(problems *pr, const char *fmt, ...) {
  pr->count++;
  if (pr->used + 2 >= pr->len) return;
  if (pr->used > 0) pr->msg[pr->used++] = '\n';
  va_list ap;
  va_start(ap, fmt);
  int n = vsnprintf(pr->msg + pr->used, pr->len - pr->used, fmt, ap);
  va_end(ap);
  if (n > 0) pr->used += (size_t)n < pr->len - pr->used ? (size_t)n : pr->len - pr->used - 1;
}

/* The table's ranges (param.h), into this accumulator. */
static void check_params(const ts_seg_params *p, problems *pr) {
  pr->msg[pr->used] = '\0';
  ts_params_check(ts_seg_param_table, p, pr->msg, pr->len, &pr->count);
  pr->used = strlen(pr->msg);
}

static int levels_ok(const ts_seg_params *p) {
  return p->levels >= 1 && p->levels <= TS_SEG_MAX_LEVELS && p->window >= 3 && p->window <= TS_SEG_MAX_WINDOW &&
         p->window % 2 == 1;
}

/* A raster of class values: one channel of whole numbers. */
static void check_raster(const ts_image_info *in, const char *name, problems *pr) {
  if (in->channels != 1)
    problem(pr, "%s has %d channels: a label raster has one (class values); take one with oiiotool --ch 0", name,
            in->channels);
  if (in->type != TS_PIX_U8 && in->type != TS_PIX_U16)
    problem(pr, "%s is %s: a label raster holds whole numbers, 8- or 16-bit", name, ts_pixtype_name(in->type));
}

static void check_channels(const ts_seg_params *p, const ts_image_info *in, const char *name, problems *pr) {
  if (p->rgb && in->channels < 3)
    problem(pr, "%s has %d channel%s: --rgb-search compares three colour channels", name, in->channels,
            in->channels == 1 ? "" : "s");
}

/* Training image k against the window at the coarsest level, and (more
 * than one level) the halves its self-segmentation cuts across its longer
 * side. */
static void check_train_size(const ts_seg_params *p, const ts_image_info *t, const char *name, problems *pr) {
  int l = p->levels - 1, n = p->window;
  int w = t->width >> l, h = t->height >> l;
  if (w < n || h < n) {
    problem(pr, "%s is %dx%d: at level %d of %d it is %dx%d, too small for a %dx%d window; use at least %dx%d, "
            "fewer --levels or a smaller --window", name, t->width, t->height, l + 1, p->levels, w, h, n, n, n << l,
            n << l);
    return;
  }
  int wide = t->width >= t->height;
  int hw = wide ? w / 2 : w, hh = wide ? h : h / 2;
  if (p->levels > 1 && (hw < n || hh < n))
    problem(pr, "%s is %dx%d: at level %d of %d the halves its self-segmentation weighs the levels with are "
            "%dx%d, too small for a %dx%d window; use at least %dx%d, fewer --levels or a smaller --window",
            name, t->width, t->height, l + 1, p->levels, hw, hh, n, n, (wide ? 2 * n : n) << l,
            (wide ? n : 2 * n) << l);
}

int ts_seg_check_headers(const ts_seg_params *p, const ts_image_info *info, const char *const *names, char *msg,
                         size_t len) {
  problems pr = {msg, len, 0, 0};
  msg[0] = '\0';
  if (p->pairs < 1 || p->pairs > TS_SEG_MAX_PAIRS) {
    problem(&pr, "%d training pairs: need 1..%d (--train IMG --labels LBL)", p->pairs, TS_SEG_MAX_PAIRS);
    return TS_EINVAL;
  }
  check_params(p, &pr);
  const ts_image_info *in = &info[TS_SEG_IN_INPUT];
  check_channels(p, in, names[TS_SEG_IN_INPUT], &pr);
  if (levels_ok(p) && ((in->width >> (p->levels - 1)) < 1 || (in->height >> (p->levels - 1)) < 1))
    problem(&pr, "%s is %dx%d: too small for %d levels", names[TS_SEG_IN_INPUT], in->width, in->height, p->levels);
  for (int k = 0; k < p->pairs; k++) {
    const ts_image_info *t = &info[ts_seg_in_train(k)], *l = &info[ts_seg_in_labels(k)];
    const char *tn = names[ts_seg_in_train(k)], *ln = names[ts_seg_in_labels(k)];
    check_channels(p, t, tn, &pr);
    if (l->width != t->width || l->height != t->height)
      problem(&pr, "%s is %dx%d, its training image %s %dx%d: a label raster has its image's size", ln, l->width,
              l->height, tn, t->width, t->height);
    check_raster(l, ln, &pr);
    if (levels_ok(p)) check_train_size(p, t, tn, &pr);
  }
  if (p->truth) {
    const ts_image_info *t = &info[ts_seg_in_truth(p)];
    const char *tn = names[ts_seg_in_truth(p)];
    if (t->width != in->width || t->height != in->height)
      problem(&pr, "%s is %dx%d, %s %dx%d: the truth has the input's size", tn, t->width, t->height,
              names[TS_SEG_IN_INPUT], in->width, in->height);
    check_raster(t, tn, &pr);
  }
  return pr.count ? TS_EINVAL : 0;
}

/* ---- label values -------------------------------------------------------- */

static unsigned value_at(const ts_image *img, size_t i) {
  return img->type == TS_PIX_U16 ? ((const uint16_t *)img->pixels)[i] : ((const uint8_t *)img->pixels)[i];
}

static size_t npixels(const ts_image *img) { return (size_t)img->width * (size_t)img->height; }

/* Marks the values of a raster in seen (65536 flags); returns how many
 * were new. */
static int mark_values(const ts_image *img, uint8_t *seen) {
  int fresh = 0;
  for (size_t i = 0; i < npixels(img); i++) {
    unsigned v = value_at(img, i);
    fresh += !seen[v];
    seen[v] = 1;
  }
  return fresh;
}

/* Up to `most` of the values flagged in seen, comma-separated, into buf
 * ("..." after them when there are more). */
static void list_values(const uint8_t *seen, int most, char *buf, size_t cap) {
  size_t o = 0;
  int n = 0;
  buf[0] = '\0';
  for (unsigned v = 0; v < 65536 && o < cap; v++) {
    if (!seen[v]) continue;
    int k = n++ < most ? snprintf(buf + o, cap - o, "%s%u", o ? ", " : "", v) : snprintf(buf + o, cap - o, ", ...");
    o += k > 0 ? (size_t)k : 0;
    if (n > most) break;
  }
}

/* The truth's values that are no class (flagged in stray, 65536 zeroed
 * flags), listed. */
static void check_truth_values(const ts_image *truth, const uint8_t *classes, uint8_t *stray, const char *name,
                               problems *pr) {
  int n = 0;
  for (size_t i = 0; i < npixels(truth); i++) {
    unsigned v = value_at(truth, i);
    n += !classes[v] && !stray[v];
    stray[v] |= !classes[v];
  }
  if (n == 0) return;
  char got[160], want[160];
  list_values(stray, 8, got, sizeof(got));
  list_values(classes, 16, want, sizeof(want));
  problem(pr, "%s holds %d label value%s no --labels raster has (%s); the classes are %s", name, n, n == 1 ? "" : "s",
          got, want);
}

int ts_seg_check(const ts_seg_params *p, const ts_image *const *in, const char *const *names, char *msg, size_t len) {
  ts_image_info info[2 * TS_SEG_MAX_PAIRS + 2];
  for (int k = 0; k < ts_seg_ninputs(p); k++)
    info[k] = (ts_image_info){in[k]->width, in[k]->height, in[k]->channels, in[k]->type};
  int rc = ts_seg_check_headers(p, info, names, msg, len);
  if (rc != 0) return rc;
  /* Flags per possible value: the classes, then the truth's strays. */
  uint8_t *seen = calloc(2 * 65536, 1);
  if (seen == NULL) {
    snprintf(msg, len, "out of memory for checking the label values");
    return TS_ENOMEM;
  }
  problems pr = {msg, len, 0, 0};
  int n = 0;
  for (int k = 0; k < p->pairs; k++) n += mark_values(in[ts_seg_in_labels(k)], seen);
  if (n > TS_SEG_MAX_CLASSES)
    problem(&pr, "the --labels rasters hold %d distinct values: at most %d classes", n, TS_SEG_MAX_CLASSES);
  if (p->truth) check_truth_values(in[ts_seg_in_truth(p)], seen, seen + 65536, names[ts_seg_in_truth(p)], &pr);
  free(seen);
  return pr.count ? TS_EINVAL : 0;
}

/* ---- classes and planes -------------------------------------------------- */

void ts_seg_classes_find(const ts_seg_params *p, const ts_image *const *in, ts_seg_classes *c) {
  memset(c, 0, sizeof(*c));
  uint8_t seen[65536 / 8] = {0}; /* a bit per value */
  for (int k = 0; k < p->pairs; k++) {
    const ts_image *l = in[ts_seg_in_labels(k)];
    c->wide |= l->type == TS_PIX_U16;
    for (size_t i = 0; i < npixels(l); i++) {
      unsigned v = value_at(l, i);
      seen[v >> 3] |= (uint8_t)(1u << (v & 7));
    }
  }
  for (unsigned v = 0; v < 65536 && c->n < TS_SEG_MAX_CLASSES; v++)
    if (seen[v >> 3] & (1u << (v & 7))) c->value[c->n++] = (uint16_t)v;
}

/* The class of value v (one of the classes): binary search. */
static uint8_t class_of(const ts_seg_classes *c, unsigned v) {
  int lo = 0, hi = c->n - 1;
  while (lo < hi) {
    int mid = (lo + hi) / 2;
    if (c->value[mid] < v) lo = mid + 1;
    else hi = mid;
  }
  return (uint8_t)lo;
}

void ts_seg_class_map(const ts_seg_classes *c, const ts_image *lbl, uint8_t *out) {
  unsigned last = 65536;
  uint8_t k = 0;
  for (size_t i = 0; i < npixels(lbl); i++) {
    unsigned v = value_at(lbl, i);
    if (v != last) k = class_of(c, v); /* runs of one value are the rule */
    last = v;
    out[i] = k;
  }
}

int ts_seg_planes(const ts_image *img, int rgb, ts_plane *planes) {
  for (int c = 0; c < (rgb ? 3 : 1); c++) {
    if (ts_plane_alloc(&planes[c], img->width, img->height) != 0) return TS_ENOMEM;
    if (rgb) ts_image_channel8(img, c, planes[c].px);
    else ts_image_luma8(img, planes[c].px);
  }
  return 0;
}
