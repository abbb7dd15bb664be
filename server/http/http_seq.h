/* http_seq.h - the operations page's sequences: the jobs that are frames
 * of a `texsyn video` run (their specs say so, jobspec.h) grouped as the
 * operator thinks of them: one sequence (the run), its chains (from a key,
 * forward or backward), each chain's frames in frame order with a
 * thumbnail of every finished one, and how many of the sequence's frames
 * are finished. Pure, as http_page.h: unit-tested without a daemon.
 *
 * A frame submitted twice (a client that was killed and ran again, a job
 * resubmitted after a coordinator lost its spool) shows once: its finished
 * job if it has one, else the newest. */
#ifndef TS_HTTP_SEQ_H
#define TS_HTTP_SEQ_H

#include <stdint.h>

#include "http_page.h"
#include "jobs.h"

/* One sequence: cells [from, to) of ts_http_seqs.cell. */
typedef struct {
  uint32_t from, to;
  uint32_t done;   /* its frames finished */
  uint64_t newest; /* its newest job shown */
} ts_http_seq;

typedef struct {
  const ts_job_frame **cell; /* by sequence, chain (key, then end), frame; one per frame */
  uint32_t ncells;
  ts_http_seq *seq; /* the newest (by its newest job) first */
  uint32_t nseq;
} ts_http_seqs;

/* Groups n frames (the snapshot's). 0 or TS_ENOMEM (*out then empty). */
int ts_http_seqs_make(const ts_job_frame *frames, uint32_t n, ts_http_seqs *out);
void ts_http_seqs_free(ts_http_seqs *g);

/* The page's "Sequences" section (nothing when there is none), and the
 * same as the JSON array of status.json's "sequences". */
void ts_http_seqs_html(ts_text *t, const ts_http_seqs *g);
void ts_http_seqs_json(ts_text *t, const ts_http_seqs *g);

#endif
