/* pieces.h - messages larger than a frame, and messages produced as the
 * socket drains (proto/PROTOCOL.md, "Messages in pieces").
 *
 * A receiver refuses any frame over its payload limit, so a message larger
 * than the peer's limit (a slice of a big reference is hundreds of MB)
 * travels as several 'M' frames, each holding one piece of it:
 *
 *   size field
 *   1    type    the message's own type (any but 'M')
 *   8    total   payload bytes of the whole message
 *   8    offset  where this piece's bytes go in it
 *   n    bytes   n >= 1
 *
 * The receiver reassembles the pieces into one frame of the message's type,
 * and checks them strictly: the first piece starts at offset 0 and declares
 * a total no larger than the receiver's message limit; each next one has
 * the same type, id and total and starts where the last ended; no other
 * frame comes in between. Anything else is a protocol error: the caller
 * closes the connection. This is transport only: it never looks inside a
 * payload, so any message type can be split.
 *
 * The sender side never holds a whole message either: a payload writer (the
 * message's ordinary ts_msg_*_write) is run in the window mode of ts_wr,
 * which keeps only the bytes of the next chunk, so the frames of a message
 * (whole or in pieces) are produced a chunk at a time into a connection's
 * output buffer as the socket drains. */
#ifndef TS_PIECES_H
#define TS_PIECES_H

#include <stddef.h>
#include <stdint.h>

#include "cursor.h"
#include "frame.h"

#define TS_PIECE_HEADER 17 /* u8 type, u64 total, u64 offset */
/* A worker's message limit unless configured. The slice of a reference at
 * the largest --max-pixels (2^28) with colour search, all on one worker, is
 * 0.94 GiB of rows, and 1 GiB more of usage counters when it is sliced
 * again inside a level. */
#define TS_PIECES_DEFAULT_MAX (2ull << 30)

/* ---- sending ------------------------------------------------------------ */

/* Writes a message's whole payload to w. Must write the same bytes every
 * time it is called for the same message (it is called once per chunk). */
typedef void ts_payload_fn(ts_wr *w, const void *arg);

/* An outgoing message being produced into frames. */
typedef struct {
  uint8_t type;
  uint32_t id;
  uint64_t total;     /* payload bytes */
  uint64_t done;      /* payload bytes produced so far */
  uint64_t frame_end; /* payload offset where the frame begun last ends */
  uint32_t piece;     /* payload bytes per piece; 0: one whole frame */
  uint32_t frames;    /* frames begun */
} ts_outmsg;

/* Payload bytes fn writes (fn NULL: an empty payload). */
uint64_t ts_payload_size(ts_payload_fn *fn, const void *arg);

/* Measures the message and decides its frames: pieces of at most
 * max_payload bytes (the receiver's frame limit) when it is larger and the
 * receiver takes pieces (pieces non-zero), else one whole frame. TS_ETOOBIG
 * if it fits neither; TS_EINVAL for a limit too small to hold a piece. */
int ts_outmsg_init(ts_outmsg *m, uint8_t type, uint32_t id, ts_payload_fn *fn, const void *arg,
                   uint32_t max_payload, int pieces, char *err);

/* Appends the next part of m's frames to out: a frame header where one
 * begins, then at most `chunk` payload bytes. 1 when the message is
 * complete, 0 if more remains, or TS_ENOMEM / TS_EINVAL (fn wrote other
 * bytes than it measured) with a message. fn and arg as for init. */
int ts_outmsg_produce(ts_outmsg *m, ts_payload_fn *fn, const void *arg, ts_wr *out, size_t chunk, char *err);

/* ---- receiving ---------------------------------------------------------- */

typedef struct {
  uint64_t max_message; /* largest message reassembled; 0: pieces refused */
  int active;           /* a message is being reassembled */
  uint8_t type;
  uint32_t id;
  uint64_t total, got;
  uint32_t count;       /* pieces of the message handed out last (0: it came whole) */
  uint8_t *buf;
  size_t cap;
  int delivered; /* buf is the message handed out last: freed at the next call */
} ts_pieces;

/* max_message 0 refuses every piece (a connection that has not finished
 * its start, or a peer that never needs them); capped at UINT32_MAX, the
 * largest payload a frame can describe. */
void ts_pieces_init(ts_pieces *p, uint64_t max_message);
void ts_pieces_free(ts_pieces *p);

/* Takes the next frame of a connection. 1: *out is a whole message - f
 * itself, or the message f's piece completed (its payload valid until the
 * next call); 0: f was a piece and more are to come; TS_EPROTO / TS_ETOOBIG
 * with a message: a bad sequence, close the connection. */
int ts_pieces_next(ts_pieces *p, const ts_frame *f, ts_frame *out, char *err);

#endif
