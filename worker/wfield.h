/* wfield.h - a worker's PatchMatch sources (the 'G' and 'T' messages,
 * PROTOCOL.md): each held whole, packed once, and passes swept over the
 * tiles a coordinator asks for. */
#ifndef TS_WFIELD_H
#define TS_WFIELD_H

#include "msg.h"
#include "patchmatch.h"
#include "replica.h"

#define TS_WFIELD_MAX 8 /* per connection */

typedef struct ts_wfield ts_wfield;

typedef struct {
  ts_wfield *slot[TS_WFIELD_MAX];
  uint32_t *in, *out; /* a pass's fields, u32 pairs */
  size_t cap;
} ts_wfields;

/* Loads (or replaces) a source: 0, or a TS_E* code with a message. */
int ts_wfield_load(ts_wfields *fs, const ts_msg_field *m, int threads, char *err);
/* Frees one source, or all (TS_UNLOAD_ALL). */
void ts_wfield_drop(ts_wfields *fs, uint32_t set);
/* Sweeps the pass's tiles over image r (the pass's query image, at its
 * state) on the pool and writes the answer into reply. */
int ts_wfield_pass(ts_wfields *fs, const ts_msg_pass *m, const ts_replica *r, ts_pool *pool, int scalar,
                   ts_wr *reply, char *err);

#endif
