/* auth.c - see auth.h. */
#include "auth.h"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <sodium.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "error.h"

/* Signed before everything else: a texsyn proof means nothing to any other
 * use of the same secret, and v1 proofs nothing to a later design. */
static const char kDomain[] = "texsyn-auth-v1";
#define TRANSCRIPT_LEN (sizeof(kDomain) - 1 + 3 + 2 * TS_AUTH_NONCE)

/* Handshake frames are small; until a peer has proved itself it cannot
 * make us buffer more than this. */
#define HANDSHAKE_MAX_FRAME 4096

int ts_auth_init(char *err) {
  if (sodium_init() < 0) return ts_error(err, TS_ENOTSUP, "cannot initialise libsodium (no random source?)");
  return 0;
}

static int enabled(const ts_auth *a) { return a != NULL && a->enabled; }

void ts_auth_clear(ts_auth *a) { sodium_memzero(a, sizeof(*a)); }

/* ---- secret file ---------------------------------------------------------- */

/* Owner-only: anyone else who can read the secret can join the cluster,
 * and anyone who can write it can lock everybody out. */
static int check_mode(const char *path, const struct stat *sb, char *err) {
  if (!S_ISREG(sb->st_mode)) return ts_error(err, TS_EINVAL, "secret file %s is not a regular file", path);
  if (sb->st_mode & (S_IRWXG | S_IRWXO))
    return ts_error(err, TS_EINVAL, "secret file %s is accessible by group or others (mode %04o); run: chmod 600 %s",
                    path, (unsigned)(sb->st_mode & 07777), path);
  return 0;
}

/* Reads at most cap bytes; *n = bytes read. */
static int read_upto(int fd, uint8_t *buf, size_t cap, size_t *n) {
  *n = 0;
  while (*n < cap) {
    ssize_t k = read(fd, buf + *n, cap - *n);
    if (k < 0 && errno == EINTR) continue;
    if (k < 0) return -1;
    if (k == 0) break;
    *n += (size_t)k;
  }
  return 0;
}

int ts_auth_load(ts_auth *a, const char *path, char *err) {
  ts_auth_clear(a);
  int fd = open(path, O_RDONLY | O_CLOEXEC);
  if (fd < 0) return ts_error(err, TS_EIO, "cannot read secret file %s: %s", path, strerror(errno));
  struct stat sb;
  int rc = fstat(fd, &sb) == 0 ? check_mode(path, &sb, err) : ts_error(err, TS_EIO, "cannot stat %s", path);
  /* Room for a secret of the maximum size, "\r\n", and one byte that
   * shows the file is longer. */
  uint8_t buf[TS_AUTH_SECRET_MAX + 3];
  size_t n = 0;
  if (rc == 0 && read_upto(fd, buf, sizeof(buf), &n) != 0)
    rc = ts_error(err, TS_EIO, "cannot read secret file %s: %s", path, strerror(errno));
  close(fd);
  if (rc == 0 && n > 0 && buf[n - 1] == '\n') n--;
  if (rc == 0 && n > 0 && buf[n - 1] == '\r') n--;
  if (rc == 0 && n == 0) rc = ts_error(err, TS_EINVAL, "secret file %s is empty; create one with: head -c 32 /dev/urandom | base64 > %s", path, path);
  if (rc == 0 && n > TS_AUTH_SECRET_MAX)
    rc = ts_error(err, TS_ETOOBIG, "secret file %s holds more than %d bytes; a secret of 32 random bytes is plenty", path,
                  TS_AUTH_SECRET_MAX);
  if (rc == 0) {
    memcpy(a->secret, buf, n);
    a->len = n;
    a->enabled = 1;
  }
  sodium_memzero(buf, sizeof(buf));
  return rc;
}

/* ---- proofs ----------------------------------------------------------------- */

void ts_auth_hmac(const ts_auth *a, const void *msg, size_t n, uint8_t out[TS_AUTH_MAC]) {
  crypto_auth_hmacsha256_state st;
  crypto_auth_hmacsha256_init(&st, a->secret, a->len);
  crypto_auth_hmacsha256_update(&st, msg, n);
  crypto_auth_hmacsha256_final(&st, out);
  sodium_memzero(&st, sizeof(st));
}

void ts_auth_mac(const ts_auth *a, int by, uint8_t connector_role, uint8_t acceptor_role,
                 const uint8_t challenge[TS_AUTH_NONCE], const uint8_t nonce[TS_AUTH_NONCE],
                 uint8_t out[TS_AUTH_MAC]) {
  uint8_t t[TRANSCRIPT_LEN], *p = t;
  memcpy(p, kDomain, sizeof(kDomain) - 1);
  p += sizeof(kDomain) - 1;
  *p++ = (uint8_t)by;
  *p++ = connector_role;
  *p++ = acceptor_role;
  memcpy(p, challenge, TS_AUTH_NONCE);
  memcpy(p + TS_AUTH_NONCE, nonce, TS_AUTH_NONCE);
  ts_auth_hmac(a, t, sizeof(t), out);
}

int ts_auth_verify(const ts_auth *a, int by, uint8_t connector_role, uint8_t acceptor_role,
                   const uint8_t challenge[TS_AUTH_NONCE], const uint8_t nonce[TS_AUTH_NONCE],
                   const uint8_t mac[TS_AUTH_MAC]) {
  uint8_t want[TS_AUTH_MAC];
  ts_auth_mac(a, by, connector_role, acceptor_role, challenge, nonce, want);
  int same = sodium_memcmp(want, mac, TS_AUTH_MAC) == 0;
  sodium_memzero(want, sizeof(want));
  return same ? 0 : TS_EAUTH;
}

/* ---- protected mode ----------------------------------------------------------- */

/* 127.0.0.0/8, ::1, and 127/8 mapped into IPv6 (a dual-stack listener). */
static int is_loopback(const struct sockaddr *sa) {
  if (sa->sa_family == AF_INET) {
    const struct sockaddr_in *in = (const struct sockaddr_in *)sa;
    return (ntohl(in->sin_addr.s_addr) >> 24) == 127;
  }
  if (sa->sa_family == AF_INET6) {
    const struct in6_addr *a6 = &((const struct sockaddr_in6 *)sa)->sin6_addr;
    if (IN6_IS_ADDR_LOOPBACK(a6)) return 1;
    return IN6_IS_ADDR_V4MAPPED(a6) && a6->s6_addr[12] == 127;
  }
  return 0;
}

int ts_auth_peer_allowed(const ts_auth *a, const struct sockaddr *peer, char *err) {
  if (enabled(a) || is_loopback(peer)) return 0;
  return ts_error(err, TS_EAUTH,
                  "protected mode: no --secret-file is configured, so only loopback connections are accepted; "
                  "configure a secret (the same --secret-file on every server, worker and client) to connect "
                  "from other hosts");
}

int ts_auth_listen_warning(const ts_auth *a, int lfd, char *msg) {
  struct sockaddr_storage ss;
  socklen_t sl = sizeof(ss);
  if (enabled(a) || getsockname(lfd, (struct sockaddr *)&ss, &sl) != 0 || is_loopback((struct sockaddr *)&ss))
    return 0;
  snprintf(msg, TS_ERR_LEN,
           "WARNING: listening beyond loopback without --secret-file: protected mode, only loopback peers are "
           "accepted; give every server, worker and client the same --secret-file to accept remote ones");
  return 1;
}

/* ---- session keys ------------------------------------------------------------ */

/* Signed before the transcript: keys for sealing mean nothing to any
 * other use of the secret. */
static const char kSealDomain[] = "texsyn-seal-v1";
#define KDF_CONTEXT "tsseal01" /* crypto_kdf's 8-byte context */
enum { KDF_CONNECTOR_TO_ACCEPTOR = 1, KDF_ACCEPTOR_TO_CONNECTOR = 2 };

void ts_auth_session_keys(const ts_auth *a, const uint8_t transcript[TS_AUTH_TRANSCRIPT], int connector,
                          uint8_t tx[TS_SEAL_KEY], uint8_t rx[TS_SEAL_KEY]) {
  uint8_t msg[sizeof(kSealDomain) - 1 + TS_AUTH_TRANSCRIPT], master[crypto_kdf_KEYBYTES];
  memcpy(msg, kSealDomain, sizeof(kSealDomain) - 1);
  memcpy(msg + sizeof(kSealDomain) - 1, transcript, TS_AUTH_TRANSCRIPT);
  _Static_assert(TS_AUTH_MAC == crypto_kdf_KEYBYTES, "the master key is an HMAC");
  ts_auth_hmac(a, msg, sizeof(msg), master);
  crypto_kdf_derive_from_key(connector ? tx : rx, TS_SEAL_KEY, KDF_CONNECTOR_TO_ACCEPTOR, KDF_CONTEXT, master);
  crypto_kdf_derive_from_key(connector ? rx : tx, TS_SEAL_KEY, KDF_ACCEPTOR_TO_CONNECTOR, KDF_CONTEXT, master);
  sodium_memzero(master, sizeof(master));
}

/* ---- the exchange ----------------------------------------------------------------- */

/* One connection start: the connection, the secret, and the hash of every
 * frame of the start, both ways, as it travelled (header and payload). */
typedef struct {
  ts_conn *c;
  const ts_auth *a;
  int timeout_ms;   /* for the whole start, not each read: a slow sender */
  double deadline;  /* cannot stretch it frame by frame */
  crypto_generichash_state th;
} hs;

static void hash_frame(hs *h, uint8_t type, uint32_t id, const void *payload, size_t len) {
  uint8_t head[TS_FRAME_HEADER];
  ts_frame_header(head, type, id, (uint32_t)len);
  crypto_generichash_update(&h->th, head, sizeof(head));
  crypto_generichash_update(&h->th, payload, len);
}

static const char *role_noun(uint8_t role) { return role == TS_ROLE_WORKER ? "worker" : "server"; }

/* The next frame, into the transcript. */
static int recv_frame(hs *h, ts_frame *f, char *err) {
  int left = (int)((h->deadline - ts_now()) * 1000.0);
  int rc = left > 0 ? ts_conn_recv(h->c, f, left, err) : TS_ETIMEDOUT;
  if (rc == TS_ETIMEDOUT)
    return ts_error(err, rc, "the connection start did not finish within %d ms", h->timeout_ms);
  if (rc < 0) return rc;
  hash_frame(h, f->type, f->id, f->payload, f->len);
  return 0;
}

/* The next frame, which must be of type `type`; an 'E' becomes its code
 * and text. */
static int expect(hs *h, uint8_t type, ts_frame *f, char *err) {
  int rc = recv_frame(h, f, err);
  if (rc < 0) return rc;
  if (f->type == TS_MSG_ERROR) {
    ts_msg_error e;
    if (ts_msg_error_read(f, &e, err) != 0) return TS_EPROTO;
    return ts_error(err, e.code, "%s: %s", h->c->peer, e.text);
  }
  if (f->type != type)
    return ts_error(err, TS_EPROTO, "%s: expected '%c' while connecting, got 0x%02x", h->c->peer, type, f->type);
  return 0;
}

/* The next 'A' frame, which must be of the given step. */
static int expect_auth(hs *h, uint8_t step, ts_msg_auth *m, char *err) {
  ts_frame f;
  int rc = expect(h, TS_MSG_AUTH, &f, err);
  if (rc == 0) rc = ts_msg_auth_read(&f, m, err);
  if (rc == 0 && m->step != step)
    rc = ts_error(err, TS_EPROTO, "%s: authentication step %u where %u was due", h->c->peer, m->step, step);
  return rc;
}

static int send_msg(hs *h, uint8_t type, uint32_t id, ts_wr *w, char *err) {
  int rc = ts_wr_status(w) != 0 ? ts_error(err, TS_ENOMEM, "out of memory")
                                 : ts_conn_send(h->c, type, id, w->buf, w->len, err);
  if (rc == 0) hash_frame(h, type, id, w->buf, w->len);
  ts_wr_free(w);
  return rc;
}

static int send_ident(hs *h, const ts_msg_ident *me, uint32_t id, char *err) {
  ts_msg_ident m = *me;
  if (enabled(h->a)) m.caps |= TS_CAP_AUTH;
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_ident_write(&w, &m);
  return send_msg(h, TS_MSG_IDENT, id, &w, err);
}

static int send_auth(hs *h, const ts_msg_auth *m, char *err) {
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_auth_write(&w, m);
  return send_msg(h, TS_MSG_AUTH, 0, &w, err);
}

/* Both sides must agree on having a secret: refusing here gives the user
 * the fix, where a mismatch found later would only say "wrong". */
static int accept_policy(const ts_auth *a, const ts_msg_ident *me, const ts_msg_ident *peer, char *err) {
  int theirs = (peer->caps & TS_CAP_AUTH) != 0;
  if (enabled(a) && !theirs)
    return ts_error(err, TS_EAUTH, "this %s requires authentication: pass --secret-file with the shared secret",
                    role_noun(me->role));
  if (!enabled(a) && theirs)
    return ts_error(err, TS_EAUTH,
                    "authentication failed: this %s has no --secret-file but the peer has one; configure the "
                    "same secret on both sides",
                    role_noun(me->role));
  return 0;
}

/* Challenge, check the response, prove ourselves. */
static int accept_exchange(hs *h, uint8_t peer_role, uint8_t my_role, char *err) {
  ts_msg_auth ch = {TS_AUTH_CHALLENGE, {0}, {0}}, resp;
  randombytes_buf(ch.nonce, sizeof(ch.nonce));
  int rc = send_auth(h, &ch, err);
  if (rc == 0) rc = expect_auth(h, TS_AUTH_RESPONSE, &resp, err);
  if (rc != 0) return rc;
  if (ts_auth_verify(h->a, TS_AUTH_BY_CONNECTOR, peer_role, my_role, ch.nonce, resp.nonce, resp.mac) != 0)
    return ts_error(err, TS_EAUTH,
                    "authentication failed: wrong secret (every server, worker and client needs the same "
                    "--secret-file)");
  ts_msg_auth proof = {TS_AUTH_PROOF, {0}, {0}};
  ts_auth_mac(h->a, TS_AUTH_BY_ACCEPTOR, peer_role, my_role, ch.nonce, resp.nonce, proof.mac);
  return send_auth(h, &proof, err);
}

static int accept_steps(hs *h, const ts_msg_ident *me, ts_msg_ident *peer, char *err) {
  ts_frame f;
  int rc = recv_frame(h, &f, err);
  if (rc < 0) return rc;
  if (f.type != TS_MSG_IDENT) return ts_error(err, TS_EPROTO, "first message must be 'I' (identify)");
  rc = ts_msg_ident_read(&f, peer, err);
  if (rc == 0) rc = accept_policy(h->a, me, peer, err);
  if (rc == 0) rc = send_ident(h, me, f.id, err);
  if (rc == 0 && enabled(h->a)) rc = accept_exchange(h, peer->role, me->role, err);
  return rc;
}

/* Answer the challenge, check the proof. */
static int connect_exchange(hs *h, uint8_t my_role, uint8_t peer_role, char *err) {
  ts_msg_auth ch, resp = {TS_AUTH_RESPONSE, {0}, {0}}, proof;
  int rc = expect_auth(h, TS_AUTH_CHALLENGE, &ch, err);
  if (rc != 0) return rc;
  randombytes_buf(resp.nonce, sizeof(resp.nonce));
  ts_auth_mac(h->a, TS_AUTH_BY_CONNECTOR, my_role, peer_role, ch.nonce, resp.nonce, resp.mac);
  rc = send_auth(h, &resp, err);
  if (rc == 0) rc = expect_auth(h, TS_AUTH_PROOF, &proof, err);
  if (rc == 0 && ts_auth_verify(h->a, TS_AUTH_BY_ACCEPTOR, my_role, peer_role, ch.nonce, resp.nonce, proof.mac) != 0)
    rc = ts_error(err, TS_EAUTH,
                  "authentication failed: %s could not prove it knows the secret (a different --secret-file there?)",
                  h->c->peer);
  return rc;
}

static int connect_steps(hs *h, const ts_msg_ident *me, ts_msg_ident *peer, char *err) {
  ts_frame f;
  int rc = send_ident(h, me, 0, err);
  if (rc == 0) rc = expect(h, TS_MSG_IDENT, &f, err);
  if (rc == 0) rc = ts_msg_ident_read(&f, peer, err);
  if (rc != 0) return rc;
  int theirs = (peer->caps & TS_CAP_AUTH) != 0;
  if (enabled(h->a) && !theirs)
    return ts_error(err, TS_EAUTH,
                    "authentication failed: %s does not authenticate (started without --secret-file, or an older "
                    "texsyn); refusing to use it",
                    h->c->peer);
  if (!enabled(h->a) && theirs)
    return ts_error(err, TS_EAUTH, "%s requires authentication: pass --secret-file with the shared secret",
                    h->c->peer);
  return enabled(h->a) ? connect_exchange(h, me->role, peer->role, err) : 0;
}

typedef int handshake_steps(hs *h, const ts_msg_ident *me, ts_msg_ident *peer, char *err);

/* Both directions run under the small handshake frame limit, and take no
 * message in pieces (which could be larger). With a secret, a start that
 * succeeded seals the connection with keys from its whole transcript: an
 * 'I' altered on the way (its capabilities, name or Modbus port, which no
 * proof covers) leaves the two sides with different keys, and the first
 * sealed frame fails. Without one the link stays plain: keys derived from
 * public nonces alone would hide nothing from whoever saw them. */
static int handshake(handshake_steps *steps, int connector, ts_conn *c, const ts_auth *a, const ts_msg_ident *me,
                     ts_msg_ident *peer, int timeout_ms, char *err) {
  uint32_t max = c->rd.max_payload;
  uint64_t max_message = c->pieces.max_message;
  c->rd.max_payload = max < HANDSHAKE_MAX_FRAME ? max : HANDSHAKE_MAX_FRAME;
  ts_conn_accept_pieces(c, 0);
  hs h = {c, a, timeout_ms, ts_now() + timeout_ms / 1000.0, {{0}}};
  crypto_generichash_init(&h.th, NULL, 0, TS_AUTH_TRANSCRIPT);
  int rc = steps(&h, me, peer, err);
  c->rd.max_payload = max;
  ts_conn_accept_pieces(c, max_message);
  uint8_t transcript[TS_AUTH_TRANSCRIPT], tx[TS_SEAL_KEY], rx[TS_SEAL_KEY];
  crypto_generichash_final(&h.th, transcript, sizeof(transcript));
  if (rc == 0 && enabled(a)) {
    ts_auth_session_keys(a, transcript, connector, tx, rx);
    rc = ts_conn_start_seal(c, tx, rx, err);
    sodium_memzero(tx, sizeof(tx));
    sodium_memzero(rx, sizeof(rx));
  }
  sodium_memzero(&h, sizeof(h));
  return rc;
}

int ts_auth_accept(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, ts_msg_ident *peer, int timeout_ms,
                   char *err) {
  return handshake(accept_steps, 0, c, a, me, peer, timeout_ms, err);
}

int ts_auth_connect(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, ts_msg_ident *peer, int timeout_ms,
                    char *err) {
  return handshake(connect_steps, 1, c, a, me, peer, timeout_ms, err);
}
