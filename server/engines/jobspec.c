/* jobspec.c - see jobspec.h. */
#include "jobspec.h"

#include <stdio.h>
#include <string.h>
#include <strings.h>

#include "error.h"
#include "util.h"

void ts_jobspec_default(ts_jobspec *s, const ts_engine *engine) {
  memset(s, 0, sizeof(*s));
  s->engine = engine ? engine : ts_engine_default();
  s->engine->params_default(&s->params);
  snprintf(s->wants.want[0], TS_EXT_LEN, "%s", s->engine->outputs[0].kind == TS_OUTPUT_FLAG ? "1" : "png");
}

const char *ts_path_ext(const char *path) {
  const char *slash = strrchr(path, '/');
  const char *dot = strrchr(path, '.');
  return dot != NULL && (slash == NULL || dot > slash) ? dot + 1 : "";
}

int ts_jobspec_format(const ts_jobspec *s, char *buf, size_t cap) {
  const ts_engine *e = s->engine;
  int n = snprintf(buf, cap, "engine=%s\n", e->name);
  if (n < 0 || (size_t)n >= cap) return TS_ETOOBIG;
  int k = e->spec_format(&s->params, buf + n, cap - (size_t)n);
  if (k < 0) return k;
  n += k;
  if (s->name[0] != '\0') {
    k = snprintf(buf + n, cap - (size_t)n, "name=%s\n", s->name);
    if (k < 0 || (size_t)k >= cap - (size_t)n) return TS_ETOOBIG;
    n += k;
  }
  if (s->seq.id[0] != '\0') {
    const ts_jobspec_seq *q = &s->seq;
    k = snprintf(buf + n, cap - (size_t)n,
                 "sequence=%s\nsequence_name=%s\nsequence_frames=%ld..%ld\nsequence_jobs=%u\n"
                 "sequence_chain=%ld..%ld\nsequence_frame=%ld\n",
                 q->id, q->name, q->first, q->last, q->jobs, q->key, q->end, q->frame);
    if (k < 0 || (size_t)k >= cap - (size_t)n) return TS_ETOOBIG;
    n += k;
  }
  for (int i = 0; i < e->noutputs; i++) {
    const char *v = s->wants.want[i];
    if (e->outputs[i].kind == TS_OUTPUT_FLAG) v = v[0] ? "1" : "0";
    k = snprintf(buf + n, cap - (size_t)n, "%s=%s\n", e->outputs[i].key, v);
    if (k < 0 || (size_t)k >= cap - (size_t)n) return TS_ETOOBIG;
    n += k;
  }
  return n;
}

/* An extension: letters and digits only, so a spec can never steer a file
 * name out of the job's directory. */
static int parse_ext(const char *v, char *out) {
  size_t n = strlen(v);
  if (n >= TS_EXT_LEN) return TS_EINVAL;
  for (size_t i = 0; i < n; i++)
    if (!((v[i] >= 'a' && v[i] <= 'z') || (v[i] >= 'A' && v[i] <= 'Z') || (v[i] >= '0' && v[i] <= '9'))) return TS_EINVAL;
  memcpy(out, v, n + 1);
  return 0;
}

int ts_ext_valid(const char *ext) {
  char tmp[TS_EXT_LEN];
  return ext[0] != '\0' && parse_ext(ext, tmp) == 0;
}

/* The formats by extension; synonyms share a canonical name. */
static const struct {
  const char *ext, *format;
} kImageExts[] = {{"png", "png"}, {"jpg", "jpeg"}, {"jpeg", "jpeg"}, {"tif", "tiff"}, {"tiff", "tiff"}, {"exr", "exr"}};

static const char *image_format(const char *ext) {
  for (size_t i = 0; i < sizeof(kImageExts) / sizeof(kImageExts[0]); i++)
    if (strcasecmp(ext, kImageExts[i].ext) == 0) return kImageExts[i].format;
  return NULL;
}

int ts_output_ext_ok(const ts_engine_output *out, const char *ext) {
  return image_format(ext) != NULL || (out->own_ext != NULL && strcasecmp(ext, out->own_ext) == 0);
}

int ts_ext_same_format(const char *a, const char *b) {
  const char *fa = image_format(a), *fb = image_format(b);
  return fa != NULL || fb != NULL ? fa == fb : strcasecmp(a, b) == 0;
}

/* An output key of the engine: its wish; TS_ENOENT if the key is no output. */
static int set_output(ts_jobspec *s, const char *k, const char *v) {
  int i = ts_engine_output_index(s->engine, k);
  if (i < 0) return TS_ENOENT;
  if (s->engine->outputs[i].kind == TS_OUTPUT_IMAGE) /* empty: not wanted */
    return (v[0] == '\0' || ts_output_ext_ok(&s->engine->outputs[i], v)) && parse_ext(v, s->wants.want[i]) == 0
               ? 0
               : TS_EINVAL;
  int on;
  if (ts_parse_int(v, 0, 1, &on) != 0) return TS_EINVAL;
  snprintf(s->wants.want[i], TS_EXT_LEN, "%s", on ? "1" : "");
  return 0;
}

static int printable(unsigned char c) { return c >= 0x20 && c < 0x7f; }

void ts_jobspec_name_of(const char *path, char *out, size_t cap) {
  const char *slash = strrchr(path, '/');
  const char *p = slash ? slash + 1 : path;
  size_t n = 0;
  for (; p[n] != '\0' && n + 1 < cap; n++) out[n] = printable((unsigned char)p[n]) ? p[n] : '?';
  out[n] = '\0';
}

void ts_jobspec_set_name(ts_jobspec *s, const char *path) { ts_jobspec_name_of(path, s->name, sizeof(s->name)); }

/* ---- the sequence a job is a frame of ---------------------------------- */

/* "A..B", each 0..TS_JOBSPEC_FRAME_MAX (either order: a chain may run
 * backward). */
static int parse_range(const char *v, long *a, long *b) {
  const char *dots = strstr(v, "..");
  char first[16];
  if (dots == NULL || (size_t)(dots - v) >= sizeof(first)) return TS_EINVAL;
  memcpy(first, v, (size_t)(dots - v));
  first[dots - v] = '\0';
  int ok = ts_parse_long(first, 0, TS_JOBSPEC_FRAME_MAX, a) == 0 &&
           ts_parse_long(dots + 2, 0, TS_JOBSPEC_FRAME_MAX, b) == 0;
  return ok ? 0 : TS_EINVAL;
}

static int parse_seq_id(const char *v, char *out) {
  if (strlen(v) != TS_JOBSPEC_SEQ_ID_LEN - 1) return TS_EINVAL;
  for (const char *p = v; *p; p++)
    if (!((*p >= '0' && *p <= '9') || (*p >= 'a' && *p <= 'f'))) return TS_EINVAL;
  memcpy(out, v, TS_JOBSPEC_SEQ_ID_LEN);
  return 0;
}

/* Names (the result's, the sequence's) are shown, never a path here. */
static int copy_printable(const char *v, char *out, size_t cap) {
  size_t n = strlen(v);
  if (n == 0 || n >= cap) return TS_EINVAL;
  for (size_t i = 0; i < n; i++)
    if (!printable((unsigned char)v[i])) return TS_EINVAL;
  memcpy(out, v, n + 1);
  return 0;
}

static const char *const kSeqKeys[] = {"sequence",      "sequence_name",  "sequence_frames",
                                       "sequence_jobs", "sequence_chain", "sequence_frame"};
#define SEQ_KEYS (sizeof(kSeqKeys) / sizeof(kSeqKeys[0]))

/* A sequence key: 0, TS_EINVAL, or TS_ENOENT for no such key. */
static int set_seq(ts_jobspec_seq *q, const char *k, const char *v) {
  size_t i = 0;
  while (i < SEQ_KEYS && strcmp(k, kSeqKeys[i]) != 0) i++;
  if (i == SEQ_KEYS) return TS_ENOENT;
  q->given |= 1u << i;
  int frames;
  switch (i) {
  case 0: return parse_seq_id(v, q->id);
  case 1: return copy_printable(v, q->name, sizeof(q->name));
  case 2: return parse_range(v, &q->first, &q->last) == 0 && q->first <= q->last ? 0 : TS_EINVAL;
  case 3:
    if (ts_parse_int(v, 1, INT32_MAX, &frames) != 0) return TS_EINVAL;
    q->jobs = (uint32_t)frames;
    return 0;
  case 4: return parse_range(v, &q->key, &q->end) == 0 && q->key != q->end ? 0 : TS_EINVAL;
  default: return ts_parse_long(v, 0, TS_JOBSPEC_FRAME_MAX, &q->frame);
  }
}

static int within(long x, long a, long b) { return a <= b ? x >= a && x <= b : x >= b && x <= a; }

/* All six keys or none, and the frames where they belong: the chain in
 * the sequence, the frame past its key. */
static int seq_complete(const ts_jobspec_seq *q, char *err) {
  if (q->given == 0) return 0;
  for (size_t i = 0; i < SEQ_KEYS; i++)
    if (!(q->given & 1u << i))
      return ts_error(err, TS_EINVAL, "job spec: %s is missing (a sequence's frame needs all of sequence, "
                      "sequence_name, _frames, _jobs, _chain and _frame)", kSeqKeys[i]);
  if (!within(q->key, q->first, q->last) || !within(q->end, q->first, q->last) || q->frame == q->key ||
      !within(q->frame, q->key, q->end))
    return ts_error(err, TS_EINVAL, "job spec: sequence_chain=%ld..%ld and sequence_frame=%ld do not fit "
                    "sequence_frames=%ld..%ld", q->key, q->end, q->frame, q->first, q->last);
  return 0;
}

/* ---- keys -------------------------------------------------------------- */

/* 0, TS_EINVAL for a bad value, TS_ENOENT for an unknown key. */
static int set_key(ts_jobspec *s, const char *k, const char *v) {
  if (strcmp(k, "engine") == 0) return strcmp(v, s->engine->name) == 0 ? 0 : TS_EINVAL;
  if (strcmp(k, "name") == 0) return copy_printable(v, s->name, sizeof(s->name));
  int rc = set_seq(&s->seq, k, v);
  if (rc != TS_ENOENT) return rc;
  rc = set_output(s, k, v);
  return rc != TS_ENOENT ? rc : s->engine->spec_set(&s->params, k, v);
}

/* The engine named by an `engine=` line of the text, else the default. */
static int find_engine(const char *text, size_t len, const ts_engine **out, char *err) {
  *out = ts_engine_default();
  for (size_t off = 0; off < len;) {
    const char *nl = memchr(text + off, '\n', len - off);
    size_t n = nl ? (size_t)(nl - (text + off)) : len - off;
    if (n > 7 && n < 64 && memcmp(text + off, "engine=", 7) == 0) {
      char name[64];
      memcpy(name, text + off + 7, n - 7);
      name[n - 7] = '\0';
      *out = ts_engine_find(name);
      if (*out == NULL) return ts_error(err, TS_EINVAL, "job spec: unknown engine '%s'", name);
      return 0;
    }
    off += n + 1;
  }
  return 0;
}

int ts_jobspec_parse(const char *text, size_t len, ts_jobspec *s, char *err) {
  const ts_engine *engine;
  int rc = find_engine(text, len, &engine, err);
  if (rc != 0) return rc;
  ts_jobspec_default(s, engine);
  size_t off = 0;
  int line = 0;
  while (off < len) {
    line++;
    const char *nl = memchr(text + off, '\n', len - off);
    size_t n = nl ? (size_t)(nl - (text + off)) : len - off;
    char buf[256];
    if (n >= sizeof(buf)) return ts_error(err, TS_EINVAL, "job spec line %d is too long", line);
    memcpy(buf, text + off, n);
    buf[n] = '\0';
    off += n + 1;
    if (n == 0) continue;
    if (memchr(buf, '\0', n) != NULL) return ts_error(err, TS_EINVAL, "job spec line %d holds a NUL byte", line);
    char *eq = strchr(buf, '=');
    if (eq == NULL) return ts_error(err, TS_EINVAL, "job spec line %d: expected key=value", line);
    *eq = '\0';
    rc = set_key(s, buf, eq + 1);
    if (rc == TS_ENOENT) return ts_error(err, TS_EINVAL, "job spec line %d: unknown key '%s'", line, buf);
    if (rc != 0) return ts_error(err, TS_EINVAL, "job spec line %d: bad value '%s' for %s", line, eq + 1, buf);
  }
  if (s->wants.want[0][0] == '\0')
    return ts_error(err, TS_EINVAL, "job spec: %s%s is required", s->engine->outputs[0].key,
                    s->engine->outputs[0].kind == TS_OUTPUT_FLAG ? "=1" : " format");
  rc = seq_complete(&s->seq, err);
  if (rc != 0) return rc;
  /* A spec must survive format and parse (the spool relies on it): an
   * engine names what it cannot default, e.g. mrf's size. */
  return s->engine->spec_complete(&s->params, err);
}
