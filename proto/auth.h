/* auth.h - who may talk to a texsyn daemon (proto/PROTOCOL.md,
 * "Authentication").
 *
 * With a shared secret (--secret-file) every connection starts with a
 * mutual challenge-response after the 'I' exchange: each side sends a
 * fresh random nonce and proves it knows the secret with an HMAC-SHA-256
 * over both nonces, both roles and who is proving, so a proof is never
 * valid twice nor in the other direction, and the secret never travels.
 * The accepting side checks the connecting side first and only then
 * proves itself, so it computes nothing for a stranger. Comparisons are
 * constant-time (libsodium).
 *
 * Without a secret a daemon is in protected mode (like Redis): it talks
 * to loopback peers only.
 *
 * After the exchange each direction gets its own key, derived from the
 * secret and a hash of every frame of the start (both 'I' frames in full,
 * the three 'A' steps), and every later frame travels sealed (seal.h):
 * someone on the path can neither read, alter, drop, replay nor reorder
 * frames without the connection ending. Without a secret (loopback only)
 * the link stays plain. */
#ifndef TS_AUTH_H
#define TS_AUTH_H

#include <stddef.h>
#include <stdint.h>
#include <sys/socket.h>

#include "msg.h"
#include "net.h"
#include "seal.h"

#define TS_AUTH_SECRET_MAX 1024 /* bytes of a secret file (one newline more) */
#define TS_AUTH_TRANSCRIPT 64   /* BLAKE2b-512 of the connection start's frames */

/* Who proves in a transcript: part of what is signed, so a proof cannot
 * be reflected back to the side that made it. */
enum { TS_AUTH_BY_CONNECTOR = 1, TS_AUTH_BY_ACCEPTOR = 2 };

typedef struct {
  int enabled; /* 0: no secret, protected mode */
  size_t len;
  uint8_t secret[TS_AUTH_SECRET_MAX];
} ts_auth;

/* Initialises the crypto library; call once at program start. */
int ts_auth_init(char *err);
/* Reads a secret file: a regular file of 1..TS_AUTH_SECRET_MAX bytes (one
 * trailing newline is not part of the secret), readable by its owner only.
 * On success a->enabled is 1. */
int ts_auth_load(ts_auth *a, const char *path, char *err);
/* Wipes the secret from memory. */
void ts_auth_clear(ts_auth *a);

/* HMAC-SHA-256 of msg keyed with the secret. */
void ts_auth_hmac(const ts_auth *a, const void *msg, size_t n, uint8_t out[TS_AUTH_MAC]);
/* The proof `by` (TS_AUTH_BY_*) sends: HMAC over the domain string, by, the
 * connecting and accepting roles, the challenge and the connector's nonce. */
void ts_auth_mac(const ts_auth *a, int by, uint8_t connector_role, uint8_t acceptor_role,
                 const uint8_t challenge[TS_AUTH_NONCE], const uint8_t nonce[TS_AUTH_NONCE],
                 uint8_t out[TS_AUTH_MAC]);
/* 0 if mac is that proof, else TS_EAUTH; constant-time. */
int ts_auth_verify(const ts_auth *a, int by, uint8_t connector_role, uint8_t acceptor_role,
                   const uint8_t challenge[TS_AUTH_NONCE], const uint8_t nonce[TS_AUTH_NONCE],
                   const uint8_t mac[TS_AUTH_MAC]);

/* The session keys of a connection whose start hashed to `transcript`:
 * master = HMAC-SHA-256(secret, "texsyn-seal-v1" || transcript), then
 * crypto_kdf subkeys 1 (connector to acceptor) and 2 (the other way),
 * context "tsseal01". tx is the key this side seals with, rx the one it
 * opens with. */
void ts_auth_session_keys(const ts_auth *a, const uint8_t transcript[TS_AUTH_TRANSCRIPT], int connector,
                          uint8_t tx[TS_SEAL_KEY], uint8_t rx[TS_SEAL_KEY]);

/* Protected mode: 0 if a peer at this address may connect (there is a
 * secret, or the peer is on loopback), else TS_EAUTH and the message to
 * send it. a may be NULL (no secret). */
int ts_auth_peer_allowed(const ts_auth *a, const struct sockaddr *peer, char *err);
/* 1 and a warning in msg (TS_ERR_LEN) if a daemon without a secret listens
 * on lfd beyond loopback, where protected mode will refuse remote peers. */
int ts_auth_listen_warning(const ts_auth *a, int lfd, char *msg);

/* timeout_ms bounds a whole connection start, not each read: a peer that
 * trickles its frames cannot stretch it (TS_ETIMEDOUT). */

/* Connection start on the accepting side: reads the peer's 'I' into *peer,
 * refuses a peer whose secret setting differs from ours, answers with our
 * 'I' (me; TS_CAP_AUTH is added when we have a secret), then, with a
 * secret, challenges the peer and proves ourselves. On failure the caller
 * sends an 'E' with err (the peer can act on it), logs it and closes:
 * TS_EAUTH for a wrong or missing secret, else a protocol error. a may be
 * NULL (no secret). With a secret, c is sealed from then on. */
int ts_auth_accept(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, ts_msg_ident *peer, int timeout_ms,
                   char *err);
/* Connection start on the connecting side: sends our 'I' (me), reads the
 * peer's into *peer and, with a secret, answers its challenge and checks
 * its proof. An 'E' from the peer becomes its code and text. With a
 * secret, c is sealed from then on. */
int ts_auth_connect(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, ts_msg_ident *peer, int timeout_ms,
                    char *err);

#endif
