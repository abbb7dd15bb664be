/* replica.h - the query image of a job, kept wherever queries are built.
 *
 * A query is a window of the image being synthesised (the MRF's canvas, a
 * StyLit target's features) at one position. Rather than sending every
 * query as a vector - ~1 KB for an 11x11 colour window, to every worker -
 * the coordinator keeps each worker's replica of that image current and
 * sends positions: the worker reads the vectors out of its replica with
 * the code the coordinator would have used (ts_vec_query, ts_vec_mask).
 *
 * The image of a level is `nplanes` fine planes (w x h, read as a torus,
 * or bounded: constrained synthesis fills part of an image that has
 * edges), optionally coarse planes (the level above, the coarse part of
 * queries) and a `done` map of pixel states (window.h: FREE, PLACED where
 * a block has been placed, FIXED where the image was given, CLOSED where it
 * is not known yet: what masked queries may use, and what placements may
 * write). An image that grows by copying (the MRF) also keeps
 * the reference planes its blocks come from and a copy map (the source
 * pixel of every pixel), so that it changes by *placements* of 8 bytes - a
 * block's position and its source - and starts a new level by predicting
 * from the copy map of the level above (ts_copy_predict), without a pixel
 * on the wire.
 *
 * A placement of block b x b (clipped at the canvas edge) copies the
 * reference pixels at src to the FREE and PLACED pixels at dst (FIXED and
 * CLOSED ones keep theirs), makes them PLACED and records the copy; if dst
 * was PLACED already (a refinement sweep), the copy it replaces leaves the
 * usage counters. Both changes come back as usage commits (search.h)
 * for the sets the replica feeds. */
#ifndef TS_REPLICA_H
#define TS_REPLICA_H

#include <stdint.h>

#include "plane.h"
#include "search.h"
#include "slice.h"
#include "window.h"

#define TS_REPLICA_MAX_PIXELS (1u << 28)

typedef struct {
  int w, h, nplanes, block, bounded;
  ts_plane fine[TS_WIN_MAX_PLANES], coarse[TS_WIN_MAX_PLANES];
  ts_levelplanes planes; /* fine and coarse, as windows read them */
  ts_plane ref[TS_WIN_MAX_PLANES];
  uint32_t *copy; /* x, y per pixel; NULL without placements */
  uint8_t *done;
  uint64_t seq; /* batches of placements applied since it was loaded */
} ts_replica;

/* Loads a replica from a description (checked: sizes within the limits,
 * copy map inside the reference). 0, TS_EINVAL or TS_ENOMEM with a
 * message. */
int ts_replica_init(ts_replica *r, const ts_replica_desc *d, char *err);
void ts_replica_free(ts_replica *r);

/* The next finer level: the image becomes the coarse planes, the fine
 * planes (w x h) are predicted from the copy map through the new level's
 * reference planes (rw x rh, nplanes of them), nothing is done yet. */
int ts_replica_next_level(ts_replica *r, int w, int h, int rw, int rh, const uint8_t *const *ref, char *err);

/* Applies placements; writes the usage commits they make to commits (room
 * for 2 n) and their count to *ncommits. Refuses, before changing
 * anything, a placement outside the canvas or the reference. */
int ts_replica_place(ts_replica *r, const ts_place *p, uint32_t n, ts_commit *commits, uint32_t *ncommits,
                     char *err);

/* Vectors (and, masked, masks) of the queries at pos[0..n) (pixel
 * indices) for window w. Refuses a position outside the image, or a
 * window reading planes the replica has not. */
int ts_replica_queries(const ts_replica *r, const ts_window *w, const uint32_t *pos, uint32_t n, int masked,
                       uint8_t *vec, uint8_t *mask, char *err);

/* Points a slice message's fine rows (fine_from_image) at the reference
 * planes of r, the image it names. Refuses (TS_EINVAL, with a message) an
 * image without reference planes, of another size, or whose rows do not
 * match the message's checksum (a replica of another level). */
int ts_replica_slice_rows(const ts_replica *r, ts_slice_desc *m, char *err);

/* Room for the vectors of a batch, grown on demand. */
typedef struct {
  uint8_t *vec, *mask;
  size_t cap;
} ts_query_scratch;
void ts_query_scratch_free(ts_query_scratch *s);

/* The vectors of a batch of positions for window w, in s. */
int ts_query_vectors(ts_query_scratch *s, const ts_replica *r, const ts_window *w, const ts_query_batch *b,
                     ts_vec_batch *out, char *err);

/* Prediction of pixel (x, y) of a w x h level from the copy map of the
 * level above (pw x ph, x then y per pixel, into a reference twice smaller
 * than this level's rw x rh): the coarse pixel's source, doubled, plus the
 * pixel's offset in its 2 x 2 cell, clamped to the reference (the copy-map
 * extrapolation of seed 002 §3.6.6). */
void ts_copy_predict(const uint32_t *prev, int pw, int ph, int w, int h, int rw, int rh, int x, int y, int *sx,
                     int *sy);

#endif
