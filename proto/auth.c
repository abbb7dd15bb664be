/* auth.c - see auth.h. */
#include "auth.h"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <sodium.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "error.h"
#include "keyring.h"

/* Signed before everything else: a texsyn proof means nothing to any other
 * use of the same secret, and v1 proofs nothing to a later design. */
static const char kDomain[] = "texsyn-auth-v2";

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

static const char *const kKinds[] = {NULL, "admin", "worker", "client", "page"};

const char *ts_auth_kind_name(uint8_t kind) { return kind >= 1 && kind <= TS_KEY_PAGE ? kKinds[kind] : NULL; }

static uint8_t kind_of(const char *s, size_t n) {
  for (uint8_t k = 1; k <= TS_KEY_PAGE; k++)
    if (strlen(kKinds[k]) == n && memcmp(kKinds[k], s, n) == 0) return k;
  return 0;
}

/* A key's name: 1..TS_AUTH_NAME_MAX of A-Z a-z 0-9 . _ @ - (it is logged,
 * and recorded as the owner of a client's jobs). */
static int name_ok(const char *s, size_t n) {
  if (n == 0 || n > TS_AUTH_NAME_MAX) return 0;
  for (size_t i = 0; i < n; i++) {
    char ch = s[i];
    if (!((ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') || strchr("._@-", ch)))
      return 0;
  }
  return 1;
}

int ts_auth_kind_allows(uint8_t kind, uint8_t role) {
  switch (kind) {
  case TS_KEY_ADMIN: return 1;
  case TS_KEY_WORKER: return role == TS_ROLE_WORKER || role == TS_ROLE_COORD;
  case TS_KEY_CLIENT: return role == TS_ROLE_CLIENT;
  default: return 0;
  }
}

/* "texsyn:KIND:NAME:HEX" with 64 hex digits. */
static int parse_typed(ts_auth *a, const char *s, size_t n, const char *what, char *err) {
  const char *k = s + strlen(TS_AUTH_KEY_PREFIX), *end = s + n;
  const char *c1 = memchr(k, ':', (size_t)(end - k));
  const char *c2 = c1 ? memchr(c1 + 1, ':', (size_t)(end - c1 - 1)) : NULL;
  uint8_t kind = c1 ? kind_of(k, (size_t)(c1 - k)) : 0;
  size_t hex = c2 ? (size_t)(end - c2 - 1) : 0;
  int hex_ok = hex == 64;
  for (size_t i = 0; hex_ok && i < hex; i++) hex_ok = strchr("0123456789abcdefABCDEF", c2[1 + i]) != NULL;
  if (kind == 0 || c2 == NULL || !name_ok(c1 + 1, (size_t)(c2 - c1 - 1)) || !hex_ok)
    return ts_error(err, TS_EINVAL,
                    "%s is not a texsyn key: want one line texsyn:KIND:NAME:HEX (KIND admin, worker, client or "
                    "page; NAME 1..%d of A-Z a-z 0-9 . _ @ -; HEX 64 hex digits); make one with: texsyn-server "
                    "--gen-secret KIND PATH",
                    what, TS_AUTH_NAME_MAX);
  a->who.kind = kind;
  memcpy(a->who.name, c1 + 1, (size_t)(c2 - c1 - 1));
  a->who.name[c2 - c1 - 1] = '\0';
  return 0;
}

/* A secret file's bytes; `what` names them in err. */
static int parse_secret(ts_auth *a, const uint8_t *buf, size_t n, const char *what, char *err) {
  ts_auth_clear(a);
  if (n > 0 && buf[n - 1] == '\n') n--;
  if (n > 0 && buf[n - 1] == '\r') n--;
  if (n == 0)
    return ts_error(err, TS_EINVAL, "secret file %s is empty; make a key with: texsyn-server --gen-secret KIND %s",
                    what, what);
  if (n > TS_AUTH_SECRET_MAX)
    return ts_error(err, TS_ETOOBIG, "secret file %s holds more than %d bytes; a secret of 32 random bytes is plenty",
                    what, TS_AUTH_SECRET_MAX);
  size_t plen = strlen(TS_AUTH_KEY_PREFIX);
  int typed = n >= plen && memcmp(buf, TS_AUTH_KEY_PREFIX, plen) == 0;
  if (!typed && n < TS_AUTH_SECRET_MIN)
    return ts_error(err, TS_EINVAL,
                    "secret file %s holds %zu bytes, fewer than %d: one sniffed connection would let a short "
                    "secret be guessed offline; make a key with: texsyn-server --gen-secret KIND PATH",
                    what, n, TS_AUTH_SECRET_MIN);
  int rc = typed ? parse_typed(a, (const char *)buf, n, what, err) : 0;
  if (rc != 0) return rc;
  if (!typed) a->who = (ts_principal){TS_KEY_ADMIN, "admin"};
  memcpy(a->secret, buf, n);
  a->len = n;
  a->enabled = 1;
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
  if (rc == 0) rc = parse_secret(a, buf, n, path, err);
  sodium_memzero(buf, sizeof(buf));
  return rc;
}

/* KIND or KIND:NAME; without a name, the file's name less ".key". */
static int gen_principal(const char *spec, const char *path, ts_principal *who, char *err) {
  const char *colon = strchr(spec, ':');
  who->kind = kind_of(spec, colon ? (size_t)(colon - spec) : strlen(spec));
  if (who->kind == 0)
    return ts_error(err, TS_EINVAL, "--gen-secret %s: the kind is admin, worker, client or page (KIND or KIND:NAME)",
                    spec);
  const char *name = colon ? colon + 1 : strrchr(path, '/') ? strrchr(path, '/') + 1 : path;
  size_t n = strlen(name);
  if (!colon && n > 4 && strcmp(name + n - 4, ".key") == 0) n -= 4;
  if (!name_ok(name, n))
    return ts_error(err, TS_EINVAL,
                    "--gen-secret %s %s: the key's name (%.*s) needs 1..%d of A-Z a-z 0-9 . _ @ -; give one as "
                    "KIND:NAME",
                    spec, path, (int)(n > 80 ? 80 : n), name, TS_AUTH_NAME_MAX);
  memcpy(who->name, name, n);
  who->name[n] = '\0';
  return 0;
}

int ts_auth_generate(const char *spec, const char *path, ts_principal *who, char *err) {
  int rc = gen_principal(spec, path, who, err);
  if (rc != 0) return rc;
  uint8_t raw[32];
  char hex[65], line[TS_AUTH_NAME_MAX + 96];
  randombytes_buf(raw, sizeof(raw));
  sodium_bin2hex(hex, sizeof(hex), raw, sizeof(raw));
  int n = snprintf(line, sizeof(line), TS_AUTH_KEY_PREFIX "%s:%s:%s\n", ts_auth_kind_name(who->kind), who->name, hex);
  sodium_memzero(raw, sizeof(raw));
  sodium_memzero(hex, sizeof(hex));
  int fd = open(path, O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
  if (fd < 0 && errno == EEXIST)
    rc = ts_error(err, TS_EINVAL, "%s exists: --gen-secret never overwrites a key (remove it first, or pick another "
                  "path)", path);
  else if (fd < 0) rc = ts_error(err, TS_EIO, "cannot create %s: %s", path, strerror(errno));
  else if (fchmod(fd, 0600) != 0 || write(fd, line, (size_t)n) != n || fsync(fd) != 0)
    rc = ts_error(err, TS_EIO, "cannot write %s: %s", path, strerror(errno));
  if (fd >= 0 && close(fd) != 0 && rc == 0) rc = ts_error(err, TS_EIO, "cannot write %s: %s", path, strerror(errno));
  if (fd >= 0 && rc != 0) unlink(path);
  sodium_memzero(line, sizeof(line));
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
  /* The name is length-prefixed, so no two (kind, name) pairs sign alike. */
  uint8_t t[sizeof(kDomain) - 1 + 5 + TS_AUTH_NAME_MAX + 2 * TS_AUTH_NONCE], *p = t;
  size_t nlen = strnlen(a->who.name, TS_AUTH_NAME_MAX);
  memcpy(p, kDomain, sizeof(kDomain) - 1);
  p += sizeof(kDomain) - 1;
  *p++ = (uint8_t)by;
  *p++ = connector_role;
  *p++ = acceptor_role;
  *p++ = a->who.kind;
  *p++ = (uint8_t)nlen;
  memcpy(p, a->who.name, nlen);
  p += nlen;
  memcpy(p, challenge, TS_AUTH_NONCE);
  memcpy(p + TS_AUTH_NONCE, nonce, TS_AUTH_NONCE);
  ts_auth_hmac(a, t, (size_t)(p + 2 * TS_AUTH_NONCE - t), out);
  sodium_memzero(t, sizeof(t));
}

int ts_auth_same_secret(const ts_auth *a, const void *given, size_t n) {
  uint8_t want[TS_AUTH_MAC], got[TS_AUTH_MAC];
  ts_auth_hmac(a, a->secret, a->len, want);
  ts_auth_hmac(a, given, n, got);
  int same = sodium_memcmp(want, got, sizeof(want)) == 0;
  sodium_memzero(want, sizeof(want));
  return same;
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
int ts_auth_is_loopback(const struct sockaddr *sa) {
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
  if (enabled(a) || ts_auth_is_loopback(peer)) return 0;
  return ts_error(err, TS_EAUTH,
                  "protected mode: no --secret-file is configured, so only loopback connections are accepted; "
                  "configure a secret (the same --secret-file on every server, worker and client) to connect "
                  "from other hosts");
}

int ts_auth_listen_warning(const ts_auth *a, int lfd, char *msg) {
  struct sockaddr_storage ss;
  socklen_t sl = sizeof(ss);
  if (enabled(a) || getsockname(lfd, (struct sockaddr *)&ss, &sl) != 0 || ts_auth_is_loopback((struct sockaddr *)&ss))
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

/* One connection start: the connection, our configuration, the key the
 * proofs use (found once the peer has named it), and the hash of every
 * frame of the start, both ways, as it travelled (header and payload). */
typedef struct {
  ts_conn *c;
  const ts_auth *a;
  ts_auth key;
  ts_principal *who;
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

static const char *role_noun(uint8_t role) {
  return role == TS_ROLE_WORKER ? "worker" : role == TS_ROLE_CLIENT ? "client" : "server";
}

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

static void name_key(ts_msg_auth *m, const ts_principal *who) {
  m->key_kind = who->kind;
  snprintf(m->key_name, sizeof(m->key_name), "%s", who->name);
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

/* Whether the key `who` may carry a link from a `connector` to an
 * `acceptor` (roles): admin any; worker between a worker and the
 * coordinator either way; client from a client; page never. */
static int link_allowed(const ts_principal *who, uint8_t connector, uint8_t acceptor, char *err) {
  const char *kind = ts_auth_kind_name(who->kind);
  int ok = who->kind == TS_KEY_ADMIN ||
           (who->kind == TS_KEY_WORKER && ((connector == TS_ROLE_WORKER && acceptor == TS_ROLE_COORD) ||
                                           (connector == TS_ROLE_COORD && acceptor == TS_ROLE_WORKER))) ||
           (who->kind == TS_KEY_CLIENT && connector == TS_ROLE_CLIENT && acceptor == TS_ROLE_COORD);
  if (ok) return 0;
  if (who->kind == TS_KEY_PAGE)
    return ts_error(err, TS_EAUTH, "refused: page key '%s' opens the operations page only, never the data plane",
                    who->name);
  return ts_error(err, TS_EAUTH,
                  "refused: %s key '%s' cannot be used by a %s; a %s needs a %s key (texsyn-server --gen-secret %s "
                  "PATH) or an admin key",
                  kind ? kind : "unknown", who->name, role_noun(connector), role_noun(connector),
                  role_noun(connector), connector == TS_ROLE_CLIENT ? "client" : "worker");
}

static const char *kWrongKey =
    "authentication failed: wrong secret (every server, worker and client needs the same --secret-file)";

/* The acceptor's keys for the response: its own, which its challenge
 * named, or (a coordinator's ring) every key of the kind and name the
 * response names. Each candidate is checked, always all of them: the time
 * taken says nothing of which one matched, nor whether the name exists. */
static int accept_check(hs *h, const ts_msg_auth *ch, const ts_msg_auth *resp, uint8_t peer_role, uint8_t my_role,
                        char *err) {
  ts_auth cand[TS_KEYRING_SAME_NAME_MAX];
  int n = 0;
  if (h->a->ring != NULL) {
    n = ts_keyring_find(h->a->ring, resp->key_kind, resp->key_name, cand, TS_KEYRING_SAME_NAME_MAX);
  } else if (resp->key_kind == h->a->who.kind && strcmp(resp->key_name, h->a->who.name) == 0) {
    cand[0] = *h->a;
    n = 1;
  }
  /* A name we do not hold is checked against a random key: the same work
   * as a wrong secret, and never a match. */
  int unknown = n == 0;
  if (unknown) {
    memset(&cand[0], 0, sizeof(cand[0]));
    randombytes_buf(cand[0].secret, TS_AUTH_SECRET_MIN);
    cand[0].len = TS_AUTH_SECRET_MIN;
    cand[0].who.kind = resp->key_kind;
    snprintf(cand[0].who.name, sizeof(cand[0].who.name), "%s", resp->key_name);
    n = 1;
  }
  int found = -1;
  for (int i = 0; i < n; i++)
    if (ts_auth_verify(&cand[i], TS_AUTH_BY_CONNECTOR, peer_role, my_role, ch->nonce, resp->nonce, resp->mac) == 0 &&
        found < 0 && !unknown)
      found = i;
  if (found >= 0) h->key = cand[found];
  sodium_memzero(cand, sizeof(cand));
  if (found < 0) {
    const char *kind = ts_auth_kind_name(resp->key_kind);
    if (resp->key_kind == TS_KEY_ADMIN && strcmp(resp->key_name, "admin") == 0) return ts_error(err, TS_EAUTH, "%s", kWrongKey);
    if (h->a->ring == NULL)
      return ts_error(err, TS_EAUTH, "authentication failed: wrong secret, or not the %s key '%s' this %s holds",
                      ts_auth_kind_name(h->a->who.kind),
                      h->a->who.name, role_noun(my_role));
    return ts_error(err, TS_EAUTH,
                    "authentication failed: wrong secret, or no %s key '%s' here (the coordinator's --keys "
                    "directory must hold that key's file)",
                    kind ? kind : "such", resp->key_name);
  }
  return link_allowed(&h->key.who, peer_role, my_role, err);
}

/* Challenge, check the response, prove ourselves. */
static int accept_exchange(hs *h, uint8_t peer_role, uint8_t my_role, char *err) {
  ts_msg_auth ch, resp;
  memset(&ch, 0, sizeof(ch));
  ch.step = TS_AUTH_CHALLENGE;
  randombytes_buf(ch.nonce, sizeof(ch.nonce));
  /* A coordinator lets the peer name its key; a worker has one, and names it. */
  if (h->a->ring == NULL) name_key(&ch, &h->a->who);
  int rc = send_auth(h, &ch, err);
  if (rc == 0) rc = expect_auth(h, TS_AUTH_RESPONSE, &resp, err);
  if (rc == 0) rc = accept_check(h, &ch, &resp, peer_role, my_role, err);
  if (rc != 0) return rc;
  ts_msg_auth proof;
  memset(&proof, 0, sizeof(proof));
  proof.step = TS_AUTH_PROOF;
  ts_auth_mac(&h->key, TS_AUTH_BY_ACCEPTOR, peer_role, my_role, ch.nonce, resp.nonce, proof.mac);
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

/* The key to answer a challenge with: the one it names, from our ring (a
 * coordinator dialling a worker), else our own. */
static int connect_key(hs *h, const ts_msg_auth *ch, uint8_t my_role, uint8_t peer_role, char *err) {
  if (h->a->ring == NULL) {
    if (ch->key_kind != 0 && (ch->key_kind != h->a->who.kind || strcmp(ch->key_name, h->a->who.name) != 0))
      return ts_error(err, TS_EAUTH, "authentication failed: %s holds %s key '%s', this side %s key '%s'",
                      h->c->peer, ts_auth_kind_name(ch->key_kind), ch->key_name, ts_auth_kind_name(h->a->who.kind),
                      h->a->who.name);
    h->key = *h->a;
    return 0;
  }
  if (ch->key_kind == 0)
    return ts_error(err, TS_EPROTO, "%s asked this coordinator to name a key: it is not a worker", h->c->peer);
  /* The newest of several keys of that name (the ring lists them so). */
  if (ts_keyring_find(h->a->ring, ch->key_kind, ch->key_name, &h->key, 1) != 1)
    return ts_error(err, TS_EAUTH,
                    "authentication failed: %s uses %s key '%s', which is not in this coordinator's --keys or "
                    "--secret-file",
                    h->c->peer, ts_auth_kind_name(ch->key_kind), ch->key_name);
  return link_allowed(&h->key.who, my_role, peer_role, err);
}

/* Answer the challenge, check the proof. */
static int connect_exchange(hs *h, uint8_t my_role, uint8_t peer_role, char *err) {
  ts_msg_auth ch, resp, proof;
  int rc = expect_auth(h, TS_AUTH_CHALLENGE, &ch, err);
  if (rc == 0) rc = connect_key(h, &ch, my_role, peer_role, err);
  if (rc != 0) return rc;
  memset(&resp, 0, sizeof(resp));
  resp.step = TS_AUTH_RESPONSE;
  name_key(&resp, &h->key.who);
  randombytes_buf(resp.nonce, sizeof(resp.nonce));
  ts_auth_mac(&h->key, TS_AUTH_BY_CONNECTOR, my_role, peer_role, ch.nonce, resp.nonce, resp.mac);
  rc = send_auth(h, &resp, err);
  if (rc == 0) rc = expect_auth(h, TS_AUTH_PROOF, &proof, err);
  if (rc == 0 && ts_auth_verify(&h->key, TS_AUTH_BY_ACCEPTOR, my_role, peer_role, ch.nonce, resp.nonce, proof.mac) != 0)
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
                     ts_msg_ident *peer, ts_principal *who, int timeout_ms, char *err) {
  uint32_t max = c->rd.max_payload;
  uint64_t max_message = c->pieces.max_message;
  c->rd.max_payload = max < HANDSHAKE_MAX_FRAME ? max : HANDSHAKE_MAX_FRAME;
  ts_conn_accept_pieces(c, 0);
  hs *h = calloc(1, sizeof(*h));
  if (h == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  h->c = c;
  h->a = a;
  h->timeout_ms = timeout_ms;
  h->deadline = ts_now() + timeout_ms / 1000.0;
  crypto_generichash_init(&h->th, NULL, 0, TS_AUTH_TRANSCRIPT);
  int rc = steps(h, me, peer, err);
  c->rd.max_payload = max;
  ts_conn_accept_pieces(c, max_message);
  uint8_t transcript[TS_AUTH_TRANSCRIPT], tx[TS_SEAL_KEY], rx[TS_SEAL_KEY];
  crypto_generichash_final(&h->th, transcript, sizeof(transcript));
  if (rc == 0 && enabled(a)) {
    ts_auth_session_keys(&h->key, transcript, connector, tx, rx);
    rc = ts_conn_start_seal(c, tx, rx, err);
    sodium_memzero(tx, sizeof(tx));
    sodium_memzero(rx, sizeof(rx));
  }
  if (who != NULL) *who = rc == 0 && enabled(a) ? h->key.who : (ts_principal){0, ""};
  sodium_memzero(h, sizeof(*h));
  free(h);
  return rc;
}

int ts_auth_accept(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, ts_msg_ident *peer, ts_principal *who,
                   int timeout_ms, char *err) {
  return handshake(accept_steps, 0, c, a, me, peer, who, timeout_ms, err);
}

int ts_auth_connect(ts_conn *c, const ts_auth *a, const ts_msg_ident *me, ts_msg_ident *peer, int timeout_ms,
                    char *err) {
  return handshake(connect_steps, 1, c, a, me, peer, NULL, timeout_ms, err);
}
