/* checkpoint.h - synthesis checkpoints as bytes: what the coordinator
 * writes to a job's spool directory after every level and every few
 * seconds inside one, so a coordinator killed mid-job resumes where its
 * last checkpoint was taken instead of from noise (and with the same
 * result bytes, see ts_mrf_checkpoint).
 *
 * The encoding is little-endian and self-checking (layout in
 * checkpoint.c): a torn, truncated, corrupted or foreign file is refused
 * with a reason, and the job then simply starts over. */
#ifndef TS_CHECKPOINT_H
#define TS_CHECKPOINT_H

#include <stddef.h>
#include <stdint.h>

#include "mrf.h"

/* A tag for the job a checkpoint belongs to: a hash of its spec text. */
uint64_t ts_checkpoint_tag(const void *spec, size_t len);

/* Encodes ck of job `tag` (a synthesis of `levels` levels) into a malloc'd
 * buffer. 0 or TS_ENOMEM. */
int ts_checkpoint_encode(const ts_mrf_checkpoint *ck, int levels, uint64_t tag, uint8_t **buf, size_t *len,
                         char *err);

/* Decodes buf into ck (which then owns its buffers: ts_checkpoint_free).
 * Refuses, with TS_EPROTO and a reason, anything that is not a whole,
 * intact checkpoint of job `tag` with at most max_pixels pixels. */
int ts_checkpoint_decode(const uint8_t *buf, size_t len, uint64_t tag, uint64_t max_pixels,
                         ts_mrf_checkpoint *ck, char *err);

/* Frees what a decoded checkpoint owns (never the engine's own state). */
void ts_checkpoint_free(ts_mrf_checkpoint *ck);

#endif
