/* seal.h - every byte after the handshake sealed (proto/PROTOCOL.md,
 * "Sealed frames").
 *
 * Once two sides with a shared secret have authenticated each other
 * (auth.h), each direction of the connection has its own 32-byte key,
 * derived from the secret and the whole handshake transcript. From then on
 * the stream of ordinary frames is carried inside sealed frames: a
 * 12-byte frame header of type 'Z' whose id is the low 32 bits of the
 * direction's counter, then at most TS_SEAL_CHUNK bytes of the plain
 * stream encrypted with XChaCha20-Poly1305 (libsodium's IETF AEAD, the
 * header as associated data, the 64-bit counter as nonce) and its 16-byte
 * tag. The counter starts at 0 and counts sealed frames, so the receiver
 * knows which one is due: one dropped, replayed, reordered or altered is
 * an error with its reason, and the connection ends.
 *
 * This sits below the frame reader: message types, lengths, ids and
 * pieces all travel inside, and every sender and receiver is covered
 * without knowing. A sealed frame is small (one recv's worth), so the
 * plain frame reader still checks a frame's length against its limit
 * before it buffers the payload. */
#ifndef TS_SEAL_H
#define TS_SEAL_H

#include <stddef.h>
#include <stdint.h>

#include "cursor.h"
#include "frame.h"

#define TS_FRAME_SEALED 'Z'
#define TS_SEAL_KEY 32
#define TS_SEAL_TAG 16
#define TS_SEAL_CHUNK 65536u /* plain bytes per sealed frame, at most */
#define TS_SEAL_MAX_PAYLOAD (TS_SEAL_CHUNK + TS_SEAL_TAG)

typedef struct {
  uint8_t tx_key[TS_SEAL_KEY], rx_key[TS_SEAL_KEY];
  uint64_t tx_seq, rx_seq; /* the counter of the next sealed frame each way */
  ts_frame_reader in;      /* sealed frames received, not opened yet */
  uint8_t *tx_buf;         /* one sealed frame being sent */
  uint8_t *rx_buf;         /* the plain bytes of the one opened last */
} ts_seal;

/* A sealed direction pair with the given keys (copied): 0 or TS_ENOMEM. */
int ts_seal_init(ts_seal *s, const uint8_t tx_key[TS_SEAL_KEY], const uint8_t rx_key[TS_SEAL_KEY]);
/* Wipes the keys and frees the buffers. */
void ts_seal_free(ts_seal *s);

/* Appends n plain bytes to out as sealed frames of at most TS_SEAL_CHUNK
 * plain bytes each. 0, or TS_ENOMEM / TS_ELIMIT (the counter is spent)
 * with a message. */
int ts_seal_append(ts_seal *s, ts_wr *out, const void *plain, size_t n, char *err);
/* Seals n (1..TS_SEAL_CHUNK) plain bytes into s->tx_buf: its length, or
 * TS_EINVAL (n out of range) / TS_ELIMIT with a message. */
int ts_seal_one(ts_seal *s, const void *plain, size_t n, char *err);

/* Opens the sealed frame f, which must be the one due: 1 and the plain
 * bytes in *plain (s->rx_buf) and *n, or TS_EPROTO naming what is wrong:
 * a plain frame where a sealed one was due, one too short for its tag, one
 * out of sequence (dropped, replayed or reordered) or one that fails
 * authentication (altered). */
int ts_seal_open(ts_seal *s, const ts_frame *f, const uint8_t **plain, size_t *n, char *err);

#endif
