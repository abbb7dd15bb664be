/* stylit_energy.c - the stylization's quality tools (stylit.h): the
 * energy of any stylized image, measured with the engine's own vectors
 * and search, and re-applying a saved NNF with the engine's vote. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "stylit.h"
#include "util.h"

/* Queries per search call: only the traffic's shape, never the result. */
#define BATCH 4096

typedef struct {
  ts_stylit_planes pl;
  ts_window win;
  ts_anchors grid;
  ts_plane pad[TS_WIN_MAX_PLANES];
  int tw, th, image, set;
} meter;

/* B' must have the target's size and the style's colour planes: 0, or
 * TS_EINVAL with the problem in msg (len bytes). */
static int image_problem(const ts_image *const *in, const ts_image *img, char *msg, size_t len) {
  const ts_image *tgt = in[ts_stylit_in_tgt(0)], *style = in[TS_STYLIT_IN_STYLE];
  int planes = img->channels < 3 ? 1 : 3, style_planes = style->channels < 3 ? 1 : 3;
  if (img->width == tgt->width && img->height == tgt->height && planes == style_planes) return 0;
  snprintf(msg, len,
           "--image is %dx%d with %d channel%s; it must have the target guides' size %dx%d and, like the "
           "%d-channel style, %s",
           img->width, img->height, img->channels, img->channels == 1 ? "" : "s", tgt->width, tgt->height,
           style->channels, style_planes == 1 ? "one or two channels" : "3 or 4 channels");
  return TS_EINVAL;
}

static int step_problem(int step, char *msg, size_t len) {
  if (step >= 1 && step <= TS_STYLIT_MAX_STEP) return 0;
  snprintf(msg, len, "--sample %d: need a step of 1..%d pixels", step, TS_STYLIT_MAX_STEP);
  return TS_EINVAL;
}

int ts_stylit_energy_check(const ts_stylit_params *p, const ts_image *const *in, const ts_image *image, int step,
                           char *msg, size_t len) {
  int rc = ts_stylit_check(p, in, msg, len);
  if (p->guides < 1 || p->guides > TS_STYLIT_MAX_GUIDES) return rc; /* then in[] has no target guide */
  char line[TS_ERR_LEN];
  int more = 0;
  if (image_problem(in, image, line, sizeof(line)) != 0) ts_problem(msg, len, &more, "%s", line);
  if (step_problem(step, line, sizeof(line)) != 0) ts_problem(msg, len, &more, "%s", line);
  return more > 0 ? TS_EINVAL : rc;
}

/* The engine's planes with B' in the style estimate's place, its window,
 * its source patches, and the padded query image open on the backend. */
static int meter_open(meter *m, const ts_stylit_params *p, const ts_image *const *in, const ts_image *img,
                      ts_search *search, char *err) {
  if (ts_stylit_planes_init(&m->pl, p, in) != 0) return ts_error(err, TS_ENOMEM, "out of memory for the inputs");
  int rc = image_problem(in, img, err, TS_ERR_LEN);
  m->tw = img->width;
  m->th = img->height;
  for (int c = 0; rc == 0 && c < m->pl.nstyle; c++) {
    if (ts_plane_alloc(&m->pl.tgt[c], m->tw, m->th) != 0) rc = ts_error(err, TS_ENOMEM, "out of memory");
    else ts_image_channel8(img, c, m->pl.tgt[c].px);
  }
  if (rc == 0) rc = ts_stylit_window(&m->win, p, &m->pl, err);
  if (rc == 0) rc = ts_anchors_init(&m->grid, &m->win, m->pl.src[0].w, m->pl.src[0].h, 0, 0, NULL, 1, NULL, err);
  const ts_plane *t[TS_WIN_MAX_PLANES];
  for (int k = 0; k < m->pl.nplanes; k++) t[k] = &m->pl.tgt[k];
  if (rc == 0 && ts_stylit_pad(t, m->pl.nplanes, p->patch / 2, m->pad) != 0)
    rc = ts_error(err, TS_ENOMEM, "out of memory for the %dx%d query image", m->tw, m->th);
  ts_replica_desc d = {.w = m->pad[0].w, .h = m->pad[0].h, .nplanes = m->pl.nplanes};
  for (int k = 0; k < m->pl.nplanes; k++) d.fine[k] = m->pad[k].px;
  if (rc == 0) rc = ts_search_image_open(search, &d, &m->image, err);
  ts_levelplanes lp = {{NULL}, {NULL}};
  for (int k = 0; k < m->pl.nplanes; k++) lp.fine[k] = &m->pl.src[k];
  ts_refset rs = {m->image, &m->win, &m->grid, &lp, NULL, NULL, 0, NULL};
  if (rc == 0) rc = ts_search_prepare(search, &rs, &m->set, err);
  return rc;
}

static void meter_close(meter *m, ts_search *search) {
  if (m->set >= 0) ts_search_release(search, m->set);
  if (m->image >= 0) ts_search_image_close(search, m->image);
  for (int k = 0; k < TS_WIN_MAX_PLANES; k++) ts_plane_free(&m->pad[k]);
  ts_anchors_free(&m->grid);
  ts_window_free(&m->win);
  ts_stylit_planes_free(&m->pl);
}

/* The best source patch of every step-th target patch: its centre into
 * centres (x, y pairs), its distance summed into *sum. */
static int search_samples(meter *m, ts_search *search, int step, int r, uint32_t *centres, uint32_t n,
                          double *sum, char *err) {
  uint32_t *pos = malloc(sizeof(*pos) * n);
  ts_l1_best *best = malloc(sizeof(*best) * n);
  int rc = pos != NULL && best != NULL ? 0 : ts_error(err, TS_ENOMEM, "out of memory for %u samples", n);
  uint32_t i = 0;
  for (int y = 0; rc == 0 && y < m->th; y += step)
    for (int x = 0; x < m->tw; x += step) pos[i++] = (uint32_t)y * (uint32_t)m->pad[0].w + (uint32_t)x;
  if (rc == 0) ts_l1_best_reset(best, n);
  for (uint32_t i0 = 0; rc == 0 && i0 < n; i0 += BATCH) {
    ts_query_batch b = {n - i0 < BATCH ? n - i0 : BATCH, pos + i0, 0, NULL, 0};
    rc = ts_search_query(search, m->set, &b, best + i0, err);
  }
  *sum = 0;
  for (uint32_t k = 0; rc == 0 && k < n; k++) {
    int x, y;
    ts_anchors_pos(&m->grid, best[k].index, &x, &y);
    centres[2 * k] = (uint32_t)(x + r);
    centres[2 * k + 1] = (uint32_t)(y + r);
    *sum += (double)best[k].dist;
  }
  free(pos);
  free(best);
  return rc;
}

/* The share of source pixels the n patches centred at centres cover. */
static int coverage(const uint32_t *centres, uint32_t n, int r, int sw, int sh, double *out, char *err) {
  size_t np = (size_t)sw * (size_t)sh, used = 0;
  uint32_t *counts = malloc(np * sizeof(*counts));
  if (counts == NULL) return ts_error(err, TS_ENOMEM, "out of memory for a %dx%d occurrence map", sw, sh);
  ts_stylit_occurrences(centres, n, r, sw, counts, np);
  for (size_t i = 0; i < np; i++) used += counts[i] > 0;
  *out = (double)used / (double)np;
  free(counts);
  return 0;
}

int ts_stylit_energy_measure(const ts_stylit_params *p, const ts_image *const *in, const ts_image *image, int step,
                             ts_search *search, ts_stylit_energy *out, char *err) {
  memset(out, 0, sizeof(*out));
  if (step_problem(step, err, TS_ERR_LEN) != 0) return TS_EINVAL;
  meter m = {.image = -1, .set = -1};
  int rc = meter_open(&m, p, in, image, search, err);
  uint32_t n = (uint32_t)(((m.tw + step - 1) / step) * ((m.th + step - 1) / step));
  uint32_t *centres = rc == 0 ? malloc(2 * sizeof(*centres) * n) : NULL;
  if (rc == 0 && centres == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory for %u samples", n);
  double sum = 0;
  if (rc == 0) rc = search_samples(&m, search, step, p->patch / 2, centres, n, &sum, err);
  if (rc == 0) rc = coverage(centres, n, p->patch / 2, m.pl.src[0].w, m.pl.src[0].h, &out->coverage, err);
  if (rc == 0) {
    out->samples = n;
    out->energy = sum / n / (double)ts_window_unit_distance(&m.win);
    out->step = step;
    out->patch = p->patch;
  }
  free(centres);
  meter_close(&m, search);
  return rc;
}

/* ---- the result as JSON ------------------------------------------------ */

int ts_stylit_energy_json(const ts_stylit_energy *e, char *buf, size_t cap) {
  int n = snprintf(buf, cap,
                   "{\"energy\": %.6f, \"coverage\": %.6f, \"coverage_of\": \"exemplar pixels\", \"samples\": %u, "
                   "\"step\": %d, \"patch_size\": %d}\n",
                   e->energy, e->coverage, e->samples, e->step, e->patch);
  return n < 0 || (size_t)n >= cap ? TS_ETOOBIG : n;
}

/* The values are read, then written again: only the very line that
 * ts_stylit_energy_json writes is taken, so what a client prints from it
 * is that line whichever process measured; and only values a measure
 * gives (a NaN would write itself back). */
int ts_stylit_energy_json_read(const char *text, size_t len, ts_stylit_energy *e, char *err) {
  char in[256], again[256];
  int end = -1;
  memset(e, 0, sizeof(*e));
  if (len < sizeof(in) && memchr(text, '\0', len) == NULL) {
    memcpy(in, text, len);
    in[len] = '\0';
    if (sscanf(in, "{\"energy\": %lf, \"coverage\": %lf, \"coverage_of\": \"exemplar pixels\", \"samples\": %u, "
                   "\"step\": %d, \"patch_size\": %d}\n%n",
               &e->energy, &e->coverage, &e->samples, &e->step, &e->patch, &end) != 5)
      end = -1;
  }
  int measured = isfinite(e->energy) && e->energy >= 0 && e->coverage >= 0 && e->coverage <= 1;
  if (end < 0 || !measured || ts_stylit_energy_json(e, again, sizeof(again)) != (int)len ||
      memcmp(again, in, len) != 0) {
    memset(e, 0, sizeof(*e));
    return ts_error(err, TS_EFORMAT,
                    "not the one-line JSON result of texsyn's energy engine ({\"energy\": E, \"coverage\": C, "
                    "...}, %zu bytes): was it made by a texsyn of another version?", len);
  }
  return 0;
}

/* ---- apply-nnf --------------------------------------------------------- */

/* Every entry the centre of a patch inside a sw x sh source: the first
 * one that is not, named. */
static int check_nnf(const uint32_t *nnf, int tw, int th, int r, int sw, int sh, char *err) {
  for (size_t i = 0; i < (size_t)tw * (size_t)th; i++) {
    uint32_t x = nnf[2 * i], y = nnf[2 * i + 1];
    if (x < (uint32_t)r || y < (uint32_t)r || x + (uint32_t)r >= (uint32_t)sw || y + (uint32_t)r >= (uint32_t)sh)
      return ts_error(err, TS_EINVAL,
                      "NNF entry of pixel (%zu, %zu) is (%u, %u): not the centre of a %dx%d patch inside the "
                      "%dx%d source (is it the NNF of a job with this exemplar's size and patch size?)",
                      i % (size_t)tw, i / (size_t)tw, x, y, 2 * r + 1, 2 * r + 1, sw, sh);
  }
  return 0;
}

int ts_stylit_apply_nnf(const uint32_t *nnf, int tw, int th, int patch, const ts_image *src, ts_image *out,
                        char *err) {
  memset(out, 0, sizeof(*out));
  if (patch < 3 || patch > TS_STYLIT_MAX_PATCH || patch % 2 == 0)
    return ts_error(err, TS_EINVAL, "--patch-size %d: need an odd number in 3..%d", patch, TS_STYLIT_MAX_PATCH);
  if (src->channels > TS_STYLIT_MAX_STYLE_CHANNELS)
    return ts_error(err, TS_EINVAL, "the source has %d channels: need 1..%d", src->channels,
                    TS_STYLIT_MAX_STYLE_CHANNELS);
  int rc = check_nnf(nnf, tw, th, patch / 2, src->width, src->height, err);
  ts_plane planes[TS_STYLIT_MAX_STYLE_CHANNELS] = {0}, voted[TS_STYLIT_MAX_STYLE_CHANNELS] = {0};
  uint8_t *o[TS_STYLIT_MAX_STYLE_CHANNELS];
  for (int c = 0; rc == 0 && c < src->channels; c++) {
    if (ts_plane_alloc(&planes[c], src->width, src->height) != 0 || ts_plane_alloc(&voted[c], tw, th) != 0)
      rc = ts_error(err, TS_ENOMEM, "out of memory");
    else ts_image_channel8(src, c, planes[c].px);
    o[c] = voted[c].px;
  }
  if (rc == 0) rc = ts_image_alloc(out, tw, th, src->channels, TS_PIX_U8, err);
  if (rc == 0) {
    ts_stylit_vote(nnf, tw, th, patch / 2, planes, src->channels, o);
    uint8_t *px = out->pixels;
    for (size_t i = 0; i < (size_t)tw * (size_t)th; i++)
      for (int c = 0; c < src->channels; c++) px[i * (size_t)src->channels + (size_t)c] = o[c][i];
  }
  for (int c = 0; c < TS_STYLIT_MAX_STYLE_CHANNELS; c++) {
    ts_plane_free(&planes[c]);
    ts_plane_free(&voted[c]);
  }
  return rc;
}
