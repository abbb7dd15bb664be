/* spool.h - what a restarted coordinator makes of a job directory
 * (SPOOL/jobs/ID, see jobs.h) and of SPOOL/last-id.
 *
 * A submission writes its input images, `client`, `ref.ext`, `inputs`
 * (for an engine with more than one input) and, last, `job.spec`; the
 * job's end writes `state`. The first input is `ref.EXT`, its extension in
 * `ref.ext` (the names from before inputs had names); each further input
 * is `NAME.EXT`, the engine's name for it (engine.h), and `inputs` holds
 * one `NAME=EXT` line per further input, in the engine's order. So a
 * directory without job.spec (and no sign of having run: a state or a
 * checkpoint) is a submission cut short before it was acknowledged, and
 * goes. Anything else was accepted, and is never dropped: a job whose
 * job.spec, ref.ext or inputs is damaged (a disk error, an edit) and that
 * still needs it is kept as failed, with a reason naming the file (an
 * input image itself is judged when the job runs: one that cannot be read
 * fails the job, naming it); a damaged `state` reruns the job
 * (synthesis is deterministic, so a job that had finished gives the same
 * bytes again); a damaged `client` only loses the job's fairness key. What
 * was found damaged comes back as a note for the log.
 *
 * Pure: the caller reads the files, these functions judge their bytes
 * (tests/unit/test_spool.c, tests/fuzz/fuzz_spool.c). */
#ifndef TS_SPOOL_H
#define TS_SPOOL_H

#include <stddef.h>
#include <stdint.h>

#include "error.h"
#include "jobspec.h"

#define TS_SPOOL_CLIENT_LEN 128
/* The client name of a job whose `client` file is damaged. */
#define TS_SPOOL_NO_CLIENT "?"

/* One file as read from disk. */
typedef struct {
  const char *data; /* its bytes (need not be NUL-terminated); NULL: not read */
  size_t len;
  const char *why; /* data NULL: why it could not be read, or NULL if it is missing */
} ts_spool_file;

typedef struct {
  ts_spool_file spec, client, ref_ext, state;
  int checkpoint; /* the directory holds a checkpoint: the job ran */
  ts_spool_file inputs; /* read only for an engine with more than one input */
} ts_spool_files;

typedef struct {
  int state;    /* TS_JOB_QUEUED (to run), TS_JOB_DONE, TS_JOB_FAILED or TS_JOB_CANCELED */
  int has_spec; /* spec is the job's; 0 only for a failed or canceled job */
  ts_jobspec spec;
  char client[TS_SPOOL_CLIENT_LEN];
  char ref_ext[TS_EXT_LEN]; /* "" when ref.ext is damaged (then the job does not run) */
  /* Extensions of inputs 1.. of the spec's engine (more_ext[k - 1] for
   * input k), from `inputs`; all "" when it is damaged. */
  char more_ext[TS_ENGINE_MAX_INPUTS - 1][TS_EXT_LEN];
  char text[TS_ERR_LEN];    /* a failed job's reason, one line */
  char note[TS_ERR_LEN];    /* what was found damaged and what became of the job; "" if nothing */
} ts_spool_job;

/* Judges the files of the job directory dir (named in every message).
 * 0: a job to keep, in *out. TS_ENOENT: a submission cut short, to be
 * removed (err says so). */
int ts_spool_read_job(const char *dir, const ts_spool_files *f, ts_spool_job *out, char *err);

/* What a name in SPOOL/jobs is. A job is deleted by renaming its
 * directory ID to ID.deleted (one atomic step: the job is there or gone)
 * before its files are removed, so a deletion a crash cut short is
 * finished by the restart, never half-done. */
typedef enum {
  TS_SPOOL_OTHER,  /* none of the spool's: left alone */
  TS_SPOOL_JOB,    /* a job's directory: its id (digits, no leading zero) */
  TS_SPOOL_DELETED /* ID.deleted: a deleted job's files, to remove */
} ts_spool_entry;
#define TS_SPOOL_DELETED_SUFFIX ".deleted"

/* The kind of name, and its id in *id unless TS_SPOOL_OTHER. */
ts_spool_entry ts_spool_entry_of(const char *name, uint64_t *id);

/* The id in the last-id file at path (named in messages): 0 and *id (1 or
 * more); TS_ENOENT if the file is missing; TS_EIO or TS_EFORMAT if it is
 * unreadable or damaged. err says which. */
int ts_spool_read_last_id(const char *path, const ts_spool_file *f, uint64_t *id, char *err);

#endif
