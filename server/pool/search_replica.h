/* search_replica.h - the query images of the cluster search backend
 * (replica.h): the coordinator's replica, which new workers are loaded
 * from, and the placements each exchange carries to the workers that hold
 * the replica's state (search_state.h says when one does). */
#ifndef TS_SEARCH_REPLICA_H
#define TS_SEARCH_REPLICA_H

#include "search_state.h"

/* search.h's image operations. */
int cl_image_open(ts_search *s, const ts_replica_desc *d, int *id, char *err);
int cl_image_place(ts_search *s, int id, const ts_place *p, uint32_t n, char *err);
int cl_image_next(ts_search *s, int id, int w, int h, int rw, int rh, const uint8_t *const *ref, char *err);
void cl_image_close(ts_search *s, int id);

/* Checks an 'R' acknowledgement against the request it answers (whose
 * tag is the image's id on the wire): 0, or TS_EPROTO. */
int cl_image_ack(const ts_frame *f, const cl_request *rq, char *err);

/* What worker w holds of the image: its record, or NULL (lock held). */
cl_synced *cl_synced_of(cl_image *im, const cl_worker *w);
void cl_mark_synced(ts_cluster *c, cl_image *im, const cl_worker *w, uint64_t seq);
/* The replica as a LOAD message (its pointers stay valid until the
 * replica changes, after the exchange). */
void cl_load_message(const cl_image *im, ts_msg_image *m);
/* The replica's LOAD message queued to worker w. */
int cl_queue_image_load(cl_worker *w, const cl_image *im, char *err);
/* The pending placements into the coordinator's replica (lock held). */
int cl_flush_image(cluster_search *cs, int id, char *err);

#endif
