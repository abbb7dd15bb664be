/* fuzz_spool.c - libFuzzer target for what a restarted coordinator makes of
 * its spool (server/jobs/spool.c): a job directory's job.spec, client, ref.ext
 * and state, and the last-id file.
 *
 * The input is a directory: a first byte saying, two bits per file (spec,
 * client, ref.ext, state), whether each is missing (0), unreadable (1) or
 * there (2, 3); a second byte with a checkpoint flag (bit 0) and the same
 * two bits for last-id (bits 1-2); then the files' bytes, in that order,
 * separated by SEP.
 *
 * Checked, besides crashes and sanitizer reports: only a directory with
 * neither job.spec nor a sign of having run (state, checkpoint) is dropped;
 * a job that will run, or be served as done, has its spec (and, to run,
 * its reference's extension); a damaged file is never passed over in
 * silence (a note for the log); a job failed for a damaged file says which
 * directory and what to do; every message is one line; a last-id read is a
 * number that prints back as the file's text. Build and run: make fuzz. */
#include <inttypes.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "jobspec.h"
#include "msg.h"
#include "spool.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

#define SEP "\n%%\n"
#define NFILES 5 /* job.spec, client, ref.ext, state, last-id */
static const char kDir[] = "/spool/jobs/7";
static const char kLastId[] = "/spool/last-id";

/* A message: NUL-terminated in TS_ERR_LEN, no control bytes. */
static void check_line(const char *s) {
  const char *end = memchr(s, '\0', TS_ERR_LEN);
  if (end == NULL) abort();
  for (; s < end; s++)
    if ((unsigned char)*s < 0x20 || *s == 0x7f) abort();
}

/* The input's files: bytes between separators, each in an exact-size copy
 * (copy[i], freed by the caller) so that reading past one is caught, and
 * how each is there. */
static void split(const uint8_t *data, size_t size, ts_spool_file f[NFILES], char *copy[NFILES], int *checkpoint) {
  int mode[NFILES] = {data[0] & 3, data[0] >> 2 & 3, data[0] >> 4 & 3, data[0] >> 6 & 3, data[1] >> 1 & 3};
  *checkpoint = data[1] & 1;
  const char *p = (const char *)data + 2, *end = (const char *)data + size;
  for (int i = 0; i < NFILES; i++) {
    const char *next = p < end ? memmem(p, (size_t)(end - p), SEP, strlen(SEP)) : NULL;
    size_t len = next != NULL ? (size_t)(next - p) : (size_t)(end - p);
    f[i] = (ts_spool_file){NULL, 0, NULL};
    copy[i] = NULL;
    if (mode[i] == 1) {
      f[i].why = "cannot read it: Permission denied";
    } else if (mode[i] >= 2 && (copy[i] = malloc(len ? len : 1)) != NULL) {
      memcpy(copy[i], p, len);
      f[i] = (ts_spool_file){copy[i], len, NULL};
    }
    p = next != NULL ? next + strlen(SEP) : end;
  }
}

static int damaged_spec(const ts_spool_file *f) {
  ts_jobspec s;
  char err[TS_ERR_LEN];
  return f->data != NULL && ts_jobspec_parse(f->data, f->len, &s, err) != 0;
}

static void check_job(const ts_spool_file f[NFILES], int checkpoint) {
  ts_spool_files in = {f[0], f[1], f[2], f[3], checkpoint};
  ts_spool_job job;
  char err[TS_ERR_LEN] = "";
  int rc = ts_spool_read_job(kDir, &in, &job, err);
  int cut_short = f[0].data == NULL && f[0].why == NULL && f[3].data == NULL && f[3].why == NULL && !checkpoint;
  if (rc == TS_ENOENT) {
    if (!cut_short || strstr(err, kDir) == NULL) abort();
    check_line(err);
    return;
  }
  if (rc != 0 || cut_short) abort();
  check_line(job.text);
  check_line(job.note);
  if (memchr(job.client, '\0', sizeof(job.client)) == NULL) abort();
  if (job.state == TS_JOB_QUEUED && (!job.has_spec || !ts_ext_valid(job.ref_ext))) abort();
  if (job.state == TS_JOB_DONE && !job.has_spec) abort();
  if (job.state != TS_JOB_QUEUED && job.state != TS_JOB_DONE && job.state != TS_JOB_FAILED &&
      job.state != TS_JOB_CANCELED)
    abort();
  char text[TS_SPEC_MAX];
  if (job.has_spec && ts_jobspec_format(&job.spec, text, sizeof(text)) < 0) abort();
  /* Damage that nothing but a note would show. */
  int unreadable = f[0].why != NULL || f[1].why != NULL || f[2].why != NULL || f[3].why != NULL;
  if ((unreadable || damaged_spec(&f[0])) && job.note[0] == '\0') abort();
  /* Failed, and not by its state file: by damage, so it must say where and what to do. */
  int said_failed = f[3].data != NULL && f[3].len >= 8 && memcmp(f[3].data, "failed: ", 8) == 0;
  if (job.state == TS_JOB_FAILED && !said_failed &&
      (strstr(job.text, kDir) == NULL || strstr(job.text, "resubmit") == NULL))
    abort();
}

static void check_last_id(const ts_spool_file *f) {
  uint64_t id = 0;
  char err[TS_ERR_LEN] = "";
  int rc = ts_spool_read_last_id(kLastId, f, &id, err);
  if (rc != 0) {
    if ((rc == TS_ENOENT) != (f->data == NULL && f->why == NULL) || strstr(err, kLastId) == NULL) abort();
    check_line(err);
    return;
  }
  if (f->data == NULL || id == 0 || id == UINT64_MAX) abort();
  char back[32];
  int n = snprintf(back, sizeof(back), "%" PRIu64, id);
  size_t len = f->len > 0 && f->data[f->len - 1] == '\n' ? f->len - 1 : f->len, zeros = 0;
  while (zeros < len && f->data[zeros] == '0') zeros++; /* an edit's "007" is 7 */
  if ((size_t)n != len - zeros || memcmp(back, f->data + zeros, len - zeros) != 0) abort(); /* another number */
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  if (size < 2) return 0;
  ts_spool_file f[NFILES];
  char *copy[NFILES];
  int checkpoint;
  split(data, size, f, copy, &checkpoint);
  check_job(f, checkpoint);
  check_last_id(&f[4]);
  for (int i = 0; i < NFILES; i++) free(copy[i]);
  return 0;
}
