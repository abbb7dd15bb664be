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
#define TS_AUTH_SECRET_MIN 32   /* fewer bytes could be guessed from one sniffed start */
#define TS_AUTH_TRANSCRIPT 64   /* BLAKE2b-512 of the connection start's frames */

/* What a key lets its holder do (SECURITY.md): admin everything (the
 * single shared secret of earlier releases is an admin key named
 * "admin"); worker join the pool, and prove the coordinator to a worker;
 * client submit and act on its own jobs; page read the operations page
 * and /metrics, never the data plane. */
enum { TS_KEY_ADMIN = 1, TS_KEY_WORKER = 2, TS_KEY_CLIENT = 3, TS_KEY_PAGE = 4 };
#define TS_AUTH_NAME_MAX 64 /* bytes of a key's name */
/* A typed key file: one line "texsyn:KIND:NAME:HEX", HEX 64 digits (32
 * random bytes); the whole line is the secret. */
#define TS_AUTH_KEY_PREFIX "texsyn:"

/* Who proves in a transcript: part of what is signed, so a proof cannot
 * be reflected back to the side that made it. */
enum { TS_AUTH_BY_CONNECTOR = 1, TS_AUTH_BY_ACCEPTOR = 2 };

typedef struct ts_keyring ts_keyring; /* keyring.h */

/* Who a key names: its kind and name. */
typedef struct {
  uint8_t kind; /* TS_KEY_* */
  char name[TS_AUTH_NAME_MAX + 1];
} ts_principal;

/* One key, or (ring set) the coordinator's table of them. */
typedef struct {
  int enabled; /* 0: no secret, protected mode */
  size_t len;
  uint8_t secret[TS_AUTH_SECRET_MAX];
  ts_principal who;  /* the key's kind and name, bound into every proof */
  ts_keyring *ring;  /* the coordinator's: a peer's key is looked up by the name it gives */
} ts_auth;

/* Initialises the crypto library; call once at program start. */
int ts_auth_init(char *err);
/* Reads a secret file: a regular file of TS_AUTH_SECRET_MIN..
 * TS_AUTH_SECRET_MAX bytes (one trailing newline is not part of the
 * secret), readable by its owner only. A typed key names its kind and
 * name; any other secret is an admin key named "admin". On success
 * a->enabled is 1. */
int ts_auth_load(ts_auth *a, const char *path, char *err);
/* Writes a fresh typed key of `kind` (admin, worker, client, page; with
 * ":NAME", else the file's name without ".key") to path: mode 0600, never
 * over an existing file. *who gets its kind and name. */
int ts_auth_generate(const char *kind, const char *path, ts_principal *who, char *err);
/* "admin", "worker", "client", "page"; NULL for another value. */
const char *ts_auth_kind_name(uint8_t kind);
/* Whether a key of `kind` may be used by a side of role `role` (TS_ROLE_*)
 * on the data plane: admin any, worker a worker or the coordinator
 * dialling one, client a client, page none. */
int ts_auth_kind_allows(uint8_t kind, uint8_t role);
/* Wipes the secret from memory. */
void ts_auth_clear(ts_auth *a);

/* 1 if given (n bytes) is a's whole secret. Compares HMACs of both under
 * the secret rather than the bytes: equal-size values, so neither the
 * time taken nor an early exit on length says how long the secret is. */
int ts_auth_same_secret(const ts_auth *a, const void *given, size_t n);
/* HMAC-SHA-256 of msg keyed with the secret. */
void ts_auth_hmac(const ts_auth *a, const void *msg, size_t n, uint8_t out[TS_AUTH_MAC]);
/* The proof `by` (TS_AUTH_BY_*) sends: HMAC over the domain string, by, the
 * connecting and accepting roles, the key's kind and name (a->who), the
 * challenge and the connector's nonce. */
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
/* 1 if sa is on loopback: 127.0.0.0/8, ::1, or 127/8 mapped into IPv6. */
int ts_auth_is_loopback(const struct sockaddr *sa);
/* 1 and a warning in msg (TS_ERR_LEN) if a daemon without a secret listens
 * on lfd beyond loopback, where protected mode will refuse remote peers. */
int ts_auth_listen_warning(const ts_auth *a, int lfd, char *msg);

/* timeout_ms bounds a whole connection start, not each read: a peer that
 * trickles its frames cannot stretch it (TS_ETIMEDOUT). */

/* Connection start on the accepting side: reads the peer's 'I' into *peer,
 * refuses a peer whose secret setting differs from ours, answers with our
 * 'I' (me; TS_CAP_AUTH is added when we have a secret), then, with a
 * secret, challenges the peer and proves ourselves. With a ring, the peer
 * names its key and must be allowed to use it in its role; with one key,
 * we name ours in the challenge. *who (may be NULL) gets the key the peer
 * proved (kind 0 without a secret). On failure the caller sends an 'E'
 * with err (the peer can act on it), logs it and closes: TS_EAUTH for a
 * wrong, unknown or misused key, else a protocol error. a may be NULL (no
 * secret). With a secret, c is sealed from then on. */
int ts_auth_accept(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, ts_msg_ident *peer, ts_principal *who,
                   int timeout_ms, char *err);
/* Connection start on the connecting side: sends our 'I' (me), reads the
 * peer's into *peer and, with a secret, answers its challenge with our key
 * (or, with a ring, the key the peer named) and checks its proof. An 'E' from the peer becomes its code and text. With a
 * secret, c is sealed from then on. */
int ts_auth_connect(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, ts_msg_ident *peer, int timeout_ms,
                    char *err);

#endif
