/* spool.c - see spool.h. */
#include "spool.h"

#include <inttypes.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "msg.h"

#define SHOWN_MAX 40 /* bytes of a damaged file quoted in a message */

/* ---- text -------------------------------------------------------------- */

static int is_control(unsigned char c) { return c < 0x20 || c == 0x7f; }

/* A file's bytes for a message: printable ASCII as is, others as \xNN,
 * cut after SHOWN_MAX bytes. */
static void shown(const char *data, size_t len, char *out, size_t cap) {
  size_t k = 0;
  for (size_t i = 0; i < len && i < SHOWN_MAX && k + 5 < cap; i++) {
    unsigned char c = (unsigned char)data[i];
    int w = c >= 0x20 && c < 0x7f && c != '\\' ? snprintf(out + k, cap - k, "%c", c)
                                                : snprintf(out + k, cap - k, "\\x%02x", c);
    k += (size_t)w;
  }
  snprintf(out + k, cap - k, "%s", len > SHOWN_MAX ? "..." : "");
}

/* Messages go to a log line and a status: control bytes (from a parse
 * error quoting the file, say) become '?'. */
static void one_line(char *s) {
  for (; *s; s++)
    if (is_control((unsigned char)*s)) *s = '?';
}

/* Appends a sentence to the note, "; " between sentences. */
static void note_add(char note[TS_ERR_LEN], const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void note_add(char note[TS_ERR_LEN], const char *fmt, ...) {
  size_t k = strlen(note);
  if (k > 0 && k + 2 < TS_ERR_LEN) k += (size_t)snprintf(note + k, TS_ERR_LEN - k, "; ");
  va_list ap;
  va_start(ap, fmt);
  if (k + 1 < TS_ERR_LEN) vsnprintf(note + k, TS_ERR_LEN - k, fmt, ap);
  va_end(ap);
}

/* Why a file that should be there is not usable, into why: missing,
 * unreadable, or (bad non-NULL) what is wrong with its bytes. */
static void why_damaged(const ts_spool_file *f, const char *bad, char *why, size_t cap) {
  if (f->data == NULL) snprintf(why, cap, "%s", f->why != NULL ? f->why : "it is missing");
  else snprintf(why, cap, "%s", bad);
}

/* why_damaged for a file whose first n bytes say the wrong thing:
 * "it says 'BYTES'" and the tail, e.g. ", not a file extension". */
static void damaged_saying(const ts_spool_file *f, size_t n, const char *tail, char *why, size_t cap) {
  char says[SHOWN_MAX * 4 + 8];
  shown(f->data != NULL ? f->data : "", n, says, sizeof(says));
  char bad[sizeof(says) + 64];
  snprintf(bad, sizeof(bad), "it says '%s'%s", says, tail);
  why_damaged(f, bad, why, cap);
}

/* ---- the files --------------------------------------------------------- */

/* job.spec: 0 and the spec, or why it is damaged. */
static int read_spec(const ts_spool_file *f, ts_jobspec *spec, char *why, size_t cap) {
  char err[TS_ERR_LEN] = "";
  if (f->data != NULL && ts_jobspec_parse(f->data, f->len, spec, err) == 0) return 0;
  why_damaged(f, err, why, cap);
  return -1;
}

/* ref.ext: the reference's extension, as the submission wrote it (an edit
 * may have added a newline); 0, or why it is damaged. */
static int read_ref_ext(const ts_spool_file *f, char ext[TS_EXT_LEN], char *why, size_t cap) {
  size_t n = f->data != NULL && f->len > 0 && f->data[f->len - 1] == '\n' ? f->len - 1 : f->len;
  if (f->data != NULL && n < TS_EXT_LEN && memchr(f->data, '\0', n) == NULL) {
    memcpy(ext, f->data, n);
    ext[n] = '\0';
    if (ts_ext_valid(ext)) return 0;
  }
  ext[0] = '\0';
  damaged_saying(f, n, ", not a file extension", why, cap);
  return -1;
}

/* inputs: for an engine with more than one input, one NAME=EXT line per
 * input after the first, names and order the engine's for the spec (so
 * nothing in the file can steer a path); 0, or why it is damaged. */
static int read_inputs(const ts_spool_file *f, const ts_jobspec *spec, char ext[][TS_EXT_LEN], char *why,
                       size_t cap) {
  ts_engine_inputs in;
  spec->engine->inputs(&spec->params, &in);
  if (in.n <= 1) return 0;
  size_t off = 0;
  int k = 1;
  for (; f->data != NULL && k < in.n; k++) {
    const char *nl = off < f->len ? memchr(f->data + off, '\n', f->len - off) : NULL;
    size_t n = nl ? (size_t)(nl - (f->data + off)) : 0, key = strlen(in.name[k]);
    if (nl == NULL || n <= key + 1 || n - key - 1 >= TS_EXT_LEN || memcmp(f->data + off, in.name[k], key) != 0 ||
        f->data[off + key] != '=')
      break;
    memcpy(ext[k - 1], f->data + off + key + 1, n - key - 1);
    ext[k - 1][n - key - 1] = '\0';
    if (memchr(ext[k - 1], '\0', n - key - 1) != NULL || !ts_ext_valid(ext[k - 1])) break;
    off += n + 1;
  }
  if (k == in.n && off == f->len) return 0;
  memset(ext, 0, sizeof(char[TS_EXT_LEN]) * (size_t)(in.n - 1));
  char tail[160];
  snprintf(tail, sizeof(tail), ", not the %d lines NAME=EXT of the job's further inputs (%s=..., ...)", in.n - 1,
           in.name[1]);
  damaged_saying(f, f->len, tail, why, cap);
  return -1;
}

/* client: the fairness key, any name a client gave (so only its length and
 * NUL bytes can tell damage); 0, or why it is damaged. */
static int read_client(const ts_spool_file *f, char client[TS_SPOOL_CLIENT_LEN], char *why, size_t cap) {
  if (f->data != NULL && f->len < TS_SPOOL_CLIENT_LEN && memchr(f->data, '\0', f->len) == NULL) {
    memcpy(client, f->data, f->len);
    client[f->len] = '\0';
    return 0;
  }
  snprintf(client, TS_SPOOL_CLIENT_LEN, "%s", TS_SPOOL_NO_CLIENT);
  why_damaged(f, f->data != NULL && f->len >= TS_SPOOL_CLIENT_LEN ? "longer than any client name"
                                                                  : "it holds a NUL byte",
              why, cap);
  return -1;
}

/* state: what jobs_finish (jobs_spool.c) writes, "done", "canceled" or "failed:
 * REASON", one line; none while the job is unfinished. The state, or -1
 * with why when it is none of these (a failed job's reason into text). */
static int read_state(const ts_spool_file *f, char text[TS_ERR_LEN], char *why, size_t cap) {
  if (f->data == NULL && f->why == NULL) return TS_JOB_QUEUED;
  size_t n = f->data != NULL && f->len > 0 && f->data[f->len - 1] == '\n' ? f->len - 1 : f->len;
  int clean = f->data != NULL;
  for (size_t i = 0; clean && i < n; i++) clean = !is_control((unsigned char)f->data[i]);
  if (clean && n == 4 && memcmp(f->data, "done", 4) == 0) return TS_JOB_DONE;
  if (clean && n == 8 && memcmp(f->data, "canceled", 8) == 0) return TS_JOB_CANCELED;
  if (clean && n >= 8 && n - 8 < TS_ERR_LEN && memcmp(f->data, "failed: ", 8) == 0) {
    memcpy(text, f->data + 8, n - 8);
    text[n - 8] = '\0';
    return TS_JOB_FAILED;
  }
  damaged_saying(f, n, "", why, cap);
  return -1;
}

/* ---- the verdict ------------------------------------------------------- */

/* A job that needs a damaged file fails with a reason naming it. */
static void fail_job(ts_spool_job *out, const char *dir, const char *file, const char *why, const char *consequence) {
  out->state = TS_JOB_FAILED;
  /* The reason quoted short enough that what to do is never cut off. */
  snprintf(out->text, sizeof(out->text), "%s in %s is damaged (%.200s); %s: resubmit it", file, dir, why,
           consequence);
  note_add(out->note, "kept as failed: %s", out->text);
}

int ts_spool_read_job(const char *dir, const ts_spool_files *f, ts_spool_job *out, char *err) {
  memset(out, 0, sizeof(*out));
  int ran = f->state.data != NULL || f->state.why != NULL || f->checkpoint;
  if (f->spec.data == NULL && f->spec.why == NULL && !ran)
    return ts_error(err, TS_ENOENT, "%s has no job.spec: a submission cut short before it was acknowledged", dir);
  char spec_why[TS_ERR_LEN] = "", ref_why[TS_ERR_LEN] = "", inputs_why[TS_ERR_LEN] = "", why[TS_ERR_LEN];
  out->has_spec = read_spec(&f->spec, &out->spec, spec_why, sizeof(spec_why)) == 0;
  int ref_ok = read_ref_ext(&f->ref_ext, out->ref_ext, ref_why, sizeof(ref_why)) == 0;
  /* Without a spec there is no telling which inputs the job had. */
  int inputs_ok = !out->has_spec || read_inputs(&f->inputs, &out->spec, out->more_ext, inputs_why,
                                                sizeof(inputs_why)) == 0;
  if (read_client(&f->client, out->client, why, sizeof(why)) != 0)
    note_add(out->note, "client in %s is damaged (%s); the job counts as client '%s'", dir, why, out->client);
  int state = read_state(&f->state, out->text, why, sizeof(why));
  if (state < 0) {
    note_add(out->note, "state in %s is damaged (%s); the job runs again", dir, why);
    state = TS_JOB_QUEUED;
  }
  out->state = state;
  if (!out->has_spec && (state == TS_JOB_QUEUED || state == TS_JOB_DONE))
    fail_job(out, dir, "job.spec", spec_why,
             state == TS_JOB_DONE ? "the job's results cannot be served" : "the job cannot run");
  else if (!ref_ok && state == TS_JOB_QUEUED)
    fail_job(out, dir, "ref.ext", ref_why, "the job's reference cannot be found, so the job cannot run");
  else if (!inputs_ok && state == TS_JOB_QUEUED)
    fail_job(out, dir, "inputs", inputs_why, "the job's input images cannot be found, so the job cannot run");
  else if (!out->has_spec || !ref_ok || !inputs_ok) /* a final job: nothing more needs the file */
    note_add(out->note, "%s in %s is damaged (%s); the job was %s already, and stays so",
             !out->has_spec ? "job.spec" : !ref_ok ? "ref.ext" : "inputs", dir,
             !out->has_spec ? spec_why : !ref_ok ? ref_why : inputs_why, ts_job_state_name(state));
  one_line(out->text);
  one_line(out->note);
  return 0;
}

int ts_spool_read_last_id(const char *path, const ts_spool_file *f, uint64_t *id, char *err) {
  if (f->data == NULL && f->why == NULL) return ts_error(err, TS_ENOENT, "%s is missing", path);
  if (f->data == NULL) return ts_error(err, TS_EIO, "%s cannot be read (%s)", path, f->why);
  size_t n = f->len > 0 && f->data[f->len - 1] == '\n' ? f->len - 1 : f->len;
  uint64_t v = 0;
  size_t i = 0;
  for (; i < n && f->data[i] >= '0' && f->data[i] <= '9'; i++) {
    unsigned d = (unsigned)(f->data[i] - '0');
    if (v > (UINT64_MAX - 1 - d) / 10) break; /* UINT64_MAX itself leaves no next id */
    v = v * 10 + d;
  }
  if (n > 0 && i == n && v > 0) {
    *id = v;
    return 0;
  }
  char says[SHOWN_MAX * 4 + 8];
  shown(f->data, n, says, sizeof(says));
  int rc = ts_error(err, TS_EFORMAT, "%s is damaged (it says '%s', not a job id)", path, says);
  one_line(err);
  return rc;
}

ts_spool_entry ts_spool_entry_of(const char *name, uint64_t *id) {
  uint64_t v = 0;
  size_t i = 0;
  for (; name[i] >= '0' && name[i] <= '9'; i++) {
    unsigned d = (unsigned)(name[i] - '0');
    if (v > (UINT64_MAX - d) / 10) return TS_SPOOL_OTHER;
    v = v * 10 + d;
  }
  ts_spool_entry kind = name[i] == '\0' ? TS_SPOOL_JOB
                        : strcmp(name + i, TS_SPOOL_DELETED_SUFFIX) == 0 ? TS_SPOOL_DELETED
                                                                         : TS_SPOOL_OTHER;
  if (i == 0 || name[0] == '0') return TS_SPOOL_OTHER;
  if (kind != TS_SPOOL_OTHER) *id = v;
  return kind;
}
