/* http_seq.c - see http_seq.h. */
#include "http_seq.h"

#include <inttypes.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"

/* ---- grouping ------------------------------------------------------------ */

static int cmp_long(long a, long b) { return a < b ? -1 : a > b; }

/* The sequence: its id and its name (two runs of the same work to other
 * outputs are two sequences). */
static int cmp_seq(const ts_job_frame *a, const ts_job_frame *b) {
  int c = strcmp(a->seq.id, b->seq.id);
  return c != 0 ? c : strcmp(a->seq.name, b->seq.name);
}

/* Sequence, chain, frame; then the job shown for the frame first: a
 * finished one, the newest. A total order (ids differ), so the same jobs
 * always group the same way. */
static int cmp_cell(const void *pa, const void *pb) {
  const ts_job_frame *a = *(const ts_job_frame *const *)pa, *b = *(const ts_job_frame *const *)pb;
  int c = cmp_seq(a, b);
  if (c == 0) c = cmp_long(a->seq.key, b->seq.key);
  if (c == 0) c = cmp_long(a->seq.end, b->seq.end);
  if (c == 0) c = cmp_long(a->seq.frame, b->seq.frame);
  if (c == 0) c = (b->state == TS_JOB_DONE) - (a->state == TS_JOB_DONE);
  return c != 0 ? c : a->id < b->id ? 1 : a->id > b->id ? -1 : 0;
}

static int same_chain(const ts_job_frame *a, const ts_job_frame *b) {
  return cmp_seq(a, b) == 0 && a->seq.key == b->seq.key && a->seq.end == b->seq.end;
}

/* The newest sequence first: the one whose newest job is. */
static int cmp_newest(const void *pa, const void *pb) {
  uint64_t a = ((const ts_http_seq *)pa)->newest, b = ((const ts_http_seq *)pb)->newest;
  return a < b ? 1 : a > b ? -1 : 0;
}

int ts_http_seqs_make(const ts_job_frame *frames, uint32_t n, ts_http_seqs *out) {
  memset(out, 0, sizeof(*out));
  if (n == 0) return 0;
  out->cell = malloc(sizeof(*out->cell) * n);
  out->seq = malloc(sizeof(*out->seq) * n);
  if (out->cell == NULL || out->seq == NULL) {
    ts_http_seqs_free(out);
    return TS_ENOMEM;
  }
  for (uint32_t i = 0; i < n; i++) out->cell[i] = &frames[i];
  qsort(out->cell, n, sizeof(*out->cell), cmp_cell);
  for (uint32_t i = 0; i < n; i++) { /* one cell per frame: the first of its jobs */
    const ts_job_frame *f = out->cell[i];
    if (out->ncells > 0) {
      const ts_job_frame *last = out->cell[out->ncells - 1];
      if (same_chain(last, f) && last->seq.frame == f->seq.frame) continue;
    }
    out->cell[out->ncells++] = f;
  }
  for (uint32_t i = 0; i < out->ncells; i++) {
    if (i == 0 || cmp_seq(out->cell[i - 1], out->cell[i]) != 0)
      out->seq[out->nseq++] = (ts_http_seq){.from = i};
    ts_http_seq *s = &out->seq[out->nseq - 1];
    s->to = i + 1;
    s->done += out->cell[i]->state == TS_JOB_DONE;
    if (out->cell[i]->id > s->newest) s->newest = out->cell[i]->id;
  }
  qsort(out->seq, out->nseq, sizeof(*out->seq), cmp_newest);
  return 0;
}

void ts_http_seqs_free(ts_http_seqs *g) {
  free(g->cell);
  free(g->seq);
  memset(g, 0, sizeof(*g));
}

/* ---- a chain ---------------------------------------------------------------- */

/* The cells of the chain starting at cell i: [i, *to). */
static uint32_t chain_end(const ts_http_seqs *g, uint32_t i, uint32_t to) {
  uint32_t k = i + 1;
  while (k < to && same_chain(g->cell[i], g->cell[k])) k++;
  return k;
}

static uint32_t chain_done(const ts_http_seqs *g, uint32_t from, uint32_t to) {
  uint32_t n = 0;
  for (uint32_t i = from; i < to; i++) n += g->cell[i]->state == TS_JOB_DONE;
  return n;
}

static const char *direction(const ts_jobspec_seq *q) { return q->end > q->key ? "forward" : "backward"; }

/* ---- HTML ---------------------------------------------------------------------- */

/* A finished frame: its small thumbnail, linked to the larger one; an
 * unfinished one: its number, its state in its class and title. */
static void html_cell(ts_text *t, const ts_job_frame *f) {
  const char *state = ts_job_state_name(f->state);
  if (f->state == TS_JOB_DONE) {
    ts_text_add(t,
                "<a href=\"/jobs/%" PRIu64 "/thumb.png\"><img class=\"frame\" data-frame=\"%ld\" data-job=\"%" PRIu64
                "\" src=\"/jobs/%" PRIu64 "/small.png\" title=\"frame %ld (job %" PRIu64 ")\" alt=\"frame %ld\"></a>",
                f->id, f->seq.frame, f->id, f->id, f->seq.frame, f->id, f->seq.frame);
    return;
  }
  ts_text_add(t, "<span class=\"frame %s\" data-frame=\"%ld\" data-job=\"%" PRIu64 "\" title=\"frame %ld (job %" PRIu64
              "): %s", state, f->seq.frame, f->id, f->seq.frame, f->id, state);
  if (f->state == TS_JOB_RUNNING) ts_text_add(t, " %.1f%%", f->permille / 10.0);
  ts_text_add(t, "\">%ld</span>", f->seq.frame);
}

static void html_chain(ts_text *t, const ts_http_seqs *g, uint32_t from, uint32_t to) {
  const ts_jobspec_seq *q = &g->cell[from]->seq;
  long step = q->end > q->key ? 1 : -1, lo = q->key + step, hi = q->end;
  if (lo > hi) {
    long x = lo;
    lo = hi;
    hi = x;
  }
  ts_text_add(t, "<tr class=\"chain\" data-key=\"%ld\" data-end=\"%ld\"><td>key %ld %s</td><td>%ld..%ld</td>"
              "<td class=n>%u of %ld</td><td class=strip>", q->key, q->end, q->key, direction(q), lo, hi,
              chain_done(g, from, to), hi - lo + 1);
  for (uint32_t i = from; i < to; i++) html_cell(t, g->cell[i]);
  ts_text_add(t, "</td></tr>\n");
}

static void html_seq(ts_text *t, const ts_http_seqs *g, const ts_http_seq *s) {
  const ts_jobspec_seq *q = &g->cell[s->from]->seq;
  ts_text_add(t, "<section class=\"sequence\" data-id=\"%s\"><h3>", q->id);
  ts_text_html(t, q->name);
  ts_text_add(t,
              "</h3>\n<p>frames %ld..%ld &middot; <progress max=\"%u\" value=\"%u\"></progress> "
              "<span class=\"done\">%u</span> of <span class=\"jobs\">%u</span> frames stylized</p>\n"
              "<table class=\"chains\"><tr><th>chain</th><th>frames</th><th>finished</th><th>frames as they finish</th>"
              "</tr>\n",
              q->first, q->last, q->jobs, s->done, s->done, q->jobs);
  for (uint32_t i = s->from; i < s->to;) {
    uint32_t end = chain_end(g, i, s->to);
    html_chain(t, g, i, end);
    i = end;
  }
  ts_text_add(t, "</table></section>\n");
}

void ts_http_seqs_html(ts_text *t, const ts_http_seqs *g) {
  if (g->nseq == 0) return;
  ts_text_add(t, "<h2>Sequences</h2>\n<div id=\"sequences\">\n");
  for (uint32_t i = 0; i < g->nseq; i++) html_seq(t, g, &g->seq[i]);
  ts_text_add(t, "</div>\n");
}

/* ---- JSON ---------------------------------------------------------------------- */

static void json_chain(ts_text *t, const ts_http_seqs *g, uint32_t from, uint32_t to) {
  const ts_jobspec_seq *q = &g->cell[from]->seq;
  ts_text_add(t, "{\"key\":%ld,\"end\":%ld,\"direction\":\"%s\",\"done\":%u,\"frames\":[", q->key, q->end, direction(q),
              chain_done(g, from, to));
  for (uint32_t i = from; i < to; i++) {
    const ts_job_frame *f = g->cell[i];
    ts_text_add(t, "%s{\"frame\":%ld,\"job\":%" PRIu64 ",\"state\":\"%s\",\"permille\":%u}", i > from ? "," : "",
                f->seq.frame, f->id, ts_job_state_name(f->state), f->permille);
  }
  ts_text_add(t, "]}");
}

void ts_http_seqs_json(ts_text *t, const ts_http_seqs *g) {
  ts_text_add(t, "[");
  for (uint32_t k = 0; k < g->nseq; k++) {
    const ts_http_seq *s = &g->seq[k];
    const ts_jobspec_seq *q = &g->cell[s->from]->seq;
    ts_text_add(t, "%s{\"id\":\"%s\",\"name\":", k ? "," : "", q->id);
    ts_text_json(t, q->name);
    ts_text_add(t, ",\"frames\":[%ld,%ld],\"jobs\":%u,\"done\":%u,\"chains\":[", q->first, q->last, q->jobs, s->done);
    for (uint32_t i = s->from; i < s->to;) {
      uint32_t end = chain_end(g, i, s->to);
      ts_text_add(t, i > s->from ? "," : "");
      json_chain(t, g, i, end);
      i = end;
    }
    ts_text_add(t, "]}");
  }
  ts_text_add(t, "]");
}
