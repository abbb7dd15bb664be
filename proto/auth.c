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

/* ---- the exchange ----------------------------------------------------------------- */

static const char *role_noun(uint8_t role) { return role == TS_ROLE_WORKER ? "worker" : "server"; }

/* The next frame, which must be of type `type`; an 'E' becomes its code
 * and text. */
static int expect(ts_conn *c, uint8_t type, int timeout_ms, ts_frame *f, char *err) {
  int rc = ts_conn_recv(c, f, timeout_ms, err);
  if (rc < 0) return rc;
  if (f->type == TS_MSG_ERROR) {
    ts_msg_error e;
    if (ts_msg_error_read(f, &e, err) != 0) return TS_EPROTO;
    return ts_error(err, e.code, "%s: %s", c->peer, e.text);
  }
  if (f->type != type)
    return ts_error(err, TS_EPROTO, "%s: expected '%c' while connecting, got 0x%02x", c->peer, type, f->type);
  return 0;
}

/* The next 'A' frame, which must be of the given step. */
static int expect_auth(ts_conn *c, uint8_t step, int timeout_ms, ts_msg_auth *m, char *err) {
  ts_frame f;
  int rc = expect(c, TS_MSG_AUTH, timeout_ms, &f, err);
  if (rc == 0) rc = ts_msg_auth_read(&f, m, err);
  if (rc == 0 && m->step != step)
    rc = ts_error(err, TS_EPROTO, "%s: authentication step %u where %u was due", c->peer, m->step, step);
  return rc;
}

static int send_msg(ts_conn *c, uint8_t type, uint32_t id, ts_wr *w, char *err) {
  int rc = ts_wr_status(w) != 0 ? ts_error(err, TS_ENOMEM, "out of memory")
                                 : ts_net_send(c->fd, type, id, w->buf, w->len, err);
  ts_wr_free(w);
  return rc;
}

static int send_ident(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, uint32_t id, char *err) {
  ts_msg_ident m = *me;
  if (enabled(a)) m.caps |= TS_CAP_AUTH;
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_ident_write(&w, &m);
  return send_msg(c, TS_MSG_IDENT, id, &w, err);
}

static int send_auth(ts_conn *c, const ts_msg_auth *m, char *err) {
  ts_wr w;
  ts_wr_init(&w);
  ts_msg_auth_write(&w, m);
  return send_msg(c, TS_MSG_AUTH, 0, &w, err);
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
static int accept_exchange(ts_conn *c, const ts_auth *a, uint8_t peer_role, uint8_t my_role, int timeout_ms,
                           char *err) {
  ts_msg_auth ch = {TS_AUTH_CHALLENGE, {0}, {0}}, resp;
  randombytes_buf(ch.nonce, sizeof(ch.nonce));
  int rc = send_auth(c, &ch, err);
  if (rc == 0) rc = expect_auth(c, TS_AUTH_RESPONSE, timeout_ms, &resp, err);
  if (rc != 0) return rc;
  if (ts_auth_verify(a, TS_AUTH_BY_CONNECTOR, peer_role, my_role, ch.nonce, resp.nonce, resp.mac) != 0)
    return ts_error(err, TS_EAUTH,
                    "authentication failed: wrong secret (every server, worker and client needs the same "
                    "--secret-file)");
  ts_msg_auth proof = {TS_AUTH_PROOF, {0}, {0}};
  ts_auth_mac(a, TS_AUTH_BY_ACCEPTOR, peer_role, my_role, ch.nonce, resp.nonce, proof.mac);
  return send_auth(c, &proof, err);
}

static int accept_steps(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, ts_msg_ident *peer, int timeout_ms,
                        char *err) {
  ts_frame f;
  int rc = ts_conn_recv(c, &f, timeout_ms, err);
  if (rc < 0) return rc;
  if (f.type != TS_MSG_IDENT) return ts_error(err, TS_EPROTO, "first message must be 'I' (identify)");
  rc = ts_msg_ident_read(&f, peer, err);
  if (rc == 0) rc = accept_policy(a, me, peer, err);
  if (rc == 0) rc = send_ident(c, a, me, f.id, err);
  if (rc == 0 && enabled(a)) rc = accept_exchange(c, a, peer->role, me->role, timeout_ms, err);
  return rc;
}

/* Answer the challenge, check the proof. */
static int connect_exchange(ts_conn *c, const ts_auth *a, uint8_t my_role, uint8_t peer_role, int timeout_ms,
                            char *err) {
  ts_msg_auth ch, resp = {TS_AUTH_RESPONSE, {0}, {0}}, proof;
  int rc = expect_auth(c, TS_AUTH_CHALLENGE, timeout_ms, &ch, err);
  if (rc != 0) return rc;
  randombytes_buf(resp.nonce, sizeof(resp.nonce));
  ts_auth_mac(a, TS_AUTH_BY_CONNECTOR, my_role, peer_role, ch.nonce, resp.nonce, resp.mac);
  rc = send_auth(c, &resp, err);
  if (rc == 0) rc = expect_auth(c, TS_AUTH_PROOF, timeout_ms, &proof, err);
  if (rc == 0 && ts_auth_verify(a, TS_AUTH_BY_ACCEPTOR, my_role, peer_role, ch.nonce, resp.nonce, proof.mac) != 0)
    rc = ts_error(err, TS_EAUTH,
                  "authentication failed: %s could not prove it knows the secret (a different --secret-file there?)",
                  c->peer);
  return rc;
}

static int connect_steps(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, ts_msg_ident *peer, int timeout_ms,
                         char *err) {
  ts_frame f;
  int rc = send_ident(c, a, me, 0, err);
  if (rc == 0) rc = expect(c, TS_MSG_IDENT, timeout_ms, &f, err);
  if (rc == 0) rc = ts_msg_ident_read(&f, peer, err);
  if (rc != 0) return rc;
  int theirs = (peer->caps & TS_CAP_AUTH) != 0;
  if (enabled(a) && !theirs)
    return ts_error(err, TS_EAUTH,
                    "authentication failed: %s does not authenticate (started without --secret-file, or an older "
                    "texsyn); refusing to use it",
                    c->peer);
  if (!enabled(a) && theirs)
    return ts_error(err, TS_EAUTH, "%s requires authentication: pass --secret-file with the shared secret", c->peer);
  return enabled(a) ? connect_exchange(c, a, me->role, peer->role, timeout_ms, err) : 0;
}

typedef int handshake_steps(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, ts_msg_ident *peer,
                            int timeout_ms, char *err);

/* Both directions run under the small handshake frame limit, and take no
 * message in pieces (which could be larger). */
static int under_handshake_limit(handshake_steps *steps, ts_conn *c, const ts_auth *a, const ts_msg_ident *me,
                                 ts_msg_ident *peer, int timeout_ms, char *err) {
  uint32_t max = c->rd.max_payload;
  uint64_t max_message = c->pieces.max_message;
  c->rd.max_payload = max < HANDSHAKE_MAX_FRAME ? max : HANDSHAKE_MAX_FRAME;
  ts_conn_accept_pieces(c, 0);
  int rc = steps(c, a, me, peer, timeout_ms, err);
  c->rd.max_payload = max;
  ts_conn_accept_pieces(c, max_message);
  return rc;
}

int ts_auth_accept(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, ts_msg_ident *peer, int timeout_ms,
                   char *err) {
  return under_handshake_limit(accept_steps, c, a, me, peer, timeout_ms, err);
}

int ts_auth_connect(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, ts_msg_ident *peer, int timeout_ms,
                    char *err) {
  return under_handshake_limit(connect_steps, c, a, me, peer, timeout_ms, err);
}
