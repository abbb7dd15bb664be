/* seal.c - see seal.h. */
#include "seal.h"

#include <sodium.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"

_Static_assert(TS_SEAL_TAG == crypto_aead_xchacha20poly1305_ietf_ABYTES, "the tag is the AEAD's");
_Static_assert(TS_SEAL_KEY == crypto_aead_xchacha20poly1305_ietf_KEYBYTES, "the key is the AEAD's");

int ts_seal_init(ts_seal *s, const uint8_t tx_key[TS_SEAL_KEY], const uint8_t rx_key[TS_SEAL_KEY]) {
  memset(s, 0, sizeof(*s));
  memcpy(s->tx_key, tx_key, TS_SEAL_KEY);
  memcpy(s->rx_key, rx_key, TS_SEAL_KEY);
  ts_frame_reader_init(&s->in, TS_SEAL_MAX_PAYLOAD);
  s->tx_buf = malloc(TS_FRAME_HEADER + TS_SEAL_MAX_PAYLOAD);
  s->rx_buf = malloc(TS_SEAL_CHUNK);
  if (s->tx_buf == NULL || s->rx_buf == NULL) {
    ts_seal_free(s);
    return TS_ENOMEM;
  }
  return 0;
}

void ts_seal_free(ts_seal *s) {
  free(s->tx_buf);
  free(s->rx_buf);
  ts_frame_reader_free(&s->in);
  sodium_memzero(s, sizeof(*s));
}

/* The nonce of sealed frame `seq` of a direction: the counter, then zeros.
 * Each direction has its own key, so no nonce is used twice with a key. */
static void nonce_of(uint64_t seq, uint8_t n[crypto_aead_xchacha20poly1305_ietf_NPUBBYTES]) {
  memset(n, 0, crypto_aead_xchacha20poly1305_ietf_NPUBBYTES);
  ts_put_le(n, seq, 8);
}

int ts_seal_one(ts_seal *s, const void *plain, size_t n, char *err) {
  if (n == 0 || n > TS_SEAL_CHUNK)
    return ts_error(err, TS_EINVAL, "sealed link: %zu plain bytes do not make a sealed frame (1..%u)", n,
                    TS_SEAL_CHUNK);
  if (s->tx_seq == UINT64_MAX) return ts_error(err, TS_ELIMIT, "sealed link: 2^64 frames sent, the counter is spent");
  uint8_t nonce[crypto_aead_xchacha20poly1305_ietf_NPUBBYTES];
  nonce_of(s->tx_seq, nonce);
  ts_frame_header(s->tx_buf, TS_FRAME_SEALED, (uint32_t)s->tx_seq, (uint32_t)(n + TS_SEAL_TAG));
  unsigned long long clen;
  crypto_aead_xchacha20poly1305_ietf_encrypt(s->tx_buf + TS_FRAME_HEADER, &clen, plain, n, s->tx_buf,
                                             TS_FRAME_HEADER, NULL, nonce, s->tx_key);
  s->tx_seq++;
  return (int)(TS_FRAME_HEADER + clen);
}

int ts_seal_append(ts_seal *s, ts_wr *out, const void *plain, size_t n, char *err) {
  const uint8_t *p = plain;
  while (n > 0) {
    size_t k = n < TS_SEAL_CHUNK ? n : TS_SEAL_CHUNK;
    int len = ts_seal_one(s, p, k, err);
    if (len < 0) return len;
    ts_wr_bytes(out, s->tx_buf, (size_t)len);
    if (ts_wr_status(out) != 0) return ts_error(err, TS_ENOMEM, "out of memory for a sealed frame");
    p += k;
    n -= k;
  }
  return 0;
}

int ts_seal_open(ts_seal *s, const ts_frame *f, const uint8_t **plain, size_t *n, char *err) {
  if (f->type != TS_FRAME_SEALED)
    return ts_error(err, TS_EPROTO, "sealed link: a plain '%c' frame where sealed frame %u was due (injected?)",
                    f->type >= 32 && f->type < 127 ? f->type : '?', (uint32_t)s->rx_seq);
  if (f->len > TS_SEAL_MAX_PAYLOAD)
    return ts_error(err, TS_ETOOBIG, "sealed link: a sealed frame of %u bytes exceeds the limit of %u", f->len,
                    TS_SEAL_MAX_PAYLOAD);
  if (f->len <= TS_SEAL_TAG)
    return ts_error(err, TS_EPROTO, "sealed link: sealed frame %u of %u bytes is too short to hold its tag (truncated)",
                    f->id, f->len);
  uint32_t due = (uint32_t)s->rx_seq;
  if (f->id != due) {
    int32_t ahead = (int32_t)(f->id - due);
    return ahead < 0 ? ts_error(err, TS_EPROTO, "sealed link: sealed frame %u arrived again where %u was due "
                                "(replayed or reordered)", f->id, due)
                     : ts_error(err, TS_EPROTO, "sealed link: sealed frame %u arrived where %u was due (%u "
                                "dropped, or reordered)", f->id, due, (uint32_t)ahead);
  }
  uint8_t header[TS_FRAME_HEADER], nonce[crypto_aead_xchacha20poly1305_ietf_NPUBBYTES];
  ts_frame_header(header, f->type, f->id, f->len);
  nonce_of(s->rx_seq, nonce);
  unsigned long long plen;
  if (crypto_aead_xchacha20poly1305_ietf_decrypt(s->rx_buf, &plen, NULL, f->payload, f->len, header,
                                                 TS_FRAME_HEADER, nonce, s->rx_key) != 0)
    return ts_error(err, TS_EPROTO, "sealed link: sealed frame %u failed authentication (altered on the way, or "
                    "keys from a tampered handshake)", due);
  s->rx_seq++;
  *plain = s->rx_buf;
  *n = (size_t)plen;
  return 1;
}
