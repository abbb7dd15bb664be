/* test_auth.c - connection authentication (proto/auth.c): HMAC against
 * published and independently computed vectors, proofs that fail on any
 * flipped bit and are bound to their transcript (direction, roles, both
 * nonces), secret-file checks, the protected-mode peer check, and both
 * halves of the handshake over a socket pair. */
#include <arpa/inet.h>
#include <netinet/in.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include "auth.h"
#include "keyring.h"
#include "error.h"
#include "ts_test.h"

static void set_secret(ts_auth *a, const char *s) {
  memset(a, 0, sizeof(*a));
  a->len = strlen(s);
  memcpy(a->secret, s, a->len);
  a->enabled = 1;
  a->who = (ts_principal){TS_KEY_ADMIN, "admin"};
}

static void hex(const uint8_t *p, size_t n, char *out) {
  for (size_t i = 0; i < n; i++) sprintf(out + 2 * i, "%02x", p[i]);
}

static int setup(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  return ts_auth_init(err);
}

/* RFC 4231, test case 2. */
static void hmac_matches_rfc4231(void **state) {
  (void)state;
  ts_auth a;
  set_secret(&a, "Jefe");
  const char *msg = "what do ya want for nothing?";
  uint8_t mac[TS_AUTH_MAC];
  char h[2 * TS_AUTH_MAC + 1];
  ts_auth_hmac(&a, msg, strlen(msg), mac);
  hex(mac, sizeof(mac), h);
  assert_string_equal(h, "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843");
}

typedef struct {
  uint8_t challenge[TS_AUTH_NONCE], nonce[TS_AUTH_NONCE];
} nonces;

static nonces counting_nonces(void) {
  nonces n;
  for (int i = 0; i < TS_AUTH_NONCE; i++) {
    n.challenge[i] = (uint8_t)i;
    n.nonce[i] = (uint8_t)(TS_AUTH_NONCE + i);
  }
  return n;
}

/* The transcript layout of PROTOCOL.md, checked against Python's hmac:
 * HMAC(key, "texsyn-auth-v2" || by || connector role || acceptor role ||
 * key kind || name length || name || challenge || nonce). */
static void proof_matches_documented_transcript(void **state) {
  (void)state;
  ts_auth a;
  set_secret(&a, "texsyn unit-test secret");
  nonces n = counting_nonces();
  uint8_t mac[TS_AUTH_MAC];
  char h[2 * TS_AUTH_MAC + 1];
  ts_auth_mac(&a, TS_AUTH_BY_CONNECTOR, TS_ROLE_CLIENT, TS_ROLE_COORD, n.challenge, n.nonce, mac);
  hex(mac, sizeof(mac), h);
  assert_string_equal(h, "95c4af40c391dbc13a333b988d7276e740bdcb43234ed74881673052c2957f62");
  ts_auth_mac(&a, TS_AUTH_BY_ACCEPTOR, TS_ROLE_CLIENT, TS_ROLE_COORD, n.challenge, n.nonce, mac);
  hex(mac, sizeof(mac), h);
  assert_string_equal(h, "55a8355d3f65bf55ec176fc69c7a3c8429991e356178340a105834d9d771ede8");
}

static void verify_refuses_every_flipped_bit(void **state) {
  (void)state;
  ts_auth a;
  set_secret(&a, "s3cret");
  nonces n = counting_nonces();
  uint8_t mac[TS_AUTH_MAC];
  ts_auth_mac(&a, TS_AUTH_BY_CONNECTOR, TS_ROLE_WORKER, TS_ROLE_COORD, n.challenge, n.nonce, mac);
  assert_int_equal(ts_auth_verify(&a, TS_AUTH_BY_CONNECTOR, TS_ROLE_WORKER, TS_ROLE_COORD, n.challenge, n.nonce, mac), 0);
  for (int bit = 0; bit < 8 * TS_AUTH_MAC; bit++) {
    mac[bit / 8] ^= (uint8_t)(1u << (bit % 8));
    assert_int_equal(ts_auth_verify(&a, TS_AUTH_BY_CONNECTOR, TS_ROLE_WORKER, TS_ROLE_COORD, n.challenge, n.nonce, mac),
                     TS_EAUTH);
    mac[bit / 8] ^= (uint8_t)(1u << (bit % 8));
  }
  for (int bit = 0; bit < 8 * TS_AUTH_NONCE; bit++) {
    n.challenge[bit / 8] ^= (uint8_t)(1u << (bit % 8));
    assert_int_equal(ts_auth_verify(&a, TS_AUTH_BY_CONNECTOR, TS_ROLE_WORKER, TS_ROLE_COORD, n.challenge, n.nonce, mac),
                     TS_EAUTH);
    n.challenge[bit / 8] ^= (uint8_t)(1u << (bit % 8));
    n.nonce[bit / 8] ^= (uint8_t)(1u << (bit % 8));
    assert_int_equal(ts_auth_verify(&a, TS_AUTH_BY_CONNECTOR, TS_ROLE_WORKER, TS_ROLE_COORD, n.challenge, n.nonce, mac),
                     TS_EAUTH);
    n.nonce[bit / 8] ^= (uint8_t)(1u << (bit % 8));
  }
}

/* A proof holds for exactly one transcript: not reflected (other
 * direction), not for other roles, not with the nonces swapped, not for a
 * fresh challenge (replay), not under another secret. */
static void proof_is_bound_to_its_transcript(void **state) {
  (void)state;
  ts_auth a, b;
  set_secret(&a, "one secret");
  set_secret(&b, "one secret!");
  nonces n = counting_nonces();
  uint8_t mac[TS_AUTH_MAC];
  ts_auth_mac(&a, TS_AUTH_BY_CONNECTOR, TS_ROLE_CLIENT, TS_ROLE_COORD, n.challenge, n.nonce, mac);
  assert_int_equal(ts_auth_verify(&a, TS_AUTH_BY_ACCEPTOR, TS_ROLE_CLIENT, TS_ROLE_COORD, n.challenge, n.nonce, mac),
                   TS_EAUTH);
  assert_int_equal(ts_auth_verify(&a, TS_AUTH_BY_CONNECTOR, TS_ROLE_WORKER, TS_ROLE_COORD, n.challenge, n.nonce, mac),
                   TS_EAUTH);
  assert_int_equal(ts_auth_verify(&a, TS_AUTH_BY_CONNECTOR, TS_ROLE_COORD, TS_ROLE_CLIENT, n.challenge, n.nonce, mac),
                   TS_EAUTH);
  assert_int_equal(ts_auth_verify(&a, TS_AUTH_BY_CONNECTOR, TS_ROLE_CLIENT, TS_ROLE_COORD, n.nonce, n.challenge, mac),
                   TS_EAUTH);
  assert_int_equal(ts_auth_verify(&b, TS_AUTH_BY_CONNECTOR, TS_ROLE_CLIENT, TS_ROLE_COORD, n.challenge, n.nonce, mac),
                   TS_EAUTH);
  uint8_t fresh[TS_AUTH_NONCE];
  memcpy(fresh, n.challenge, sizeof(fresh));
  fresh[TS_AUTH_NONCE - 1] ^= 0x80;
  assert_int_equal(ts_auth_verify(&a, TS_AUTH_BY_CONNECTOR, TS_ROLE_CLIENT, TS_ROLE_COORD, fresh, n.nonce, mac),
                   TS_EAUTH);
  /* The same secret bytes under another key kind or name prove nothing:
   * a key's identity is signed, so a lookup by name cannot be steered. */
  ts_auth c = a;
  c.who = (ts_principal){TS_KEY_CLIENT, "admin"};
  assert_int_equal(ts_auth_verify(&c, TS_AUTH_BY_CONNECTOR, TS_ROLE_CLIENT, TS_ROLE_COORD, n.challenge, n.nonce, mac),
                   TS_EAUTH);
  c.who = (ts_principal){TS_KEY_ADMIN, "admin2"};
  assert_int_equal(ts_auth_verify(&c, TS_AUTH_BY_CONNECTOR, TS_ROLE_CLIENT, TS_ROLE_COORD, n.challenge, n.nonce, mac),
                   TS_EAUTH);
}

/* ---- secret files ---------------------------------------------------------- */

typedef struct {
  char path[64];
} tmpfile_t;

static tmpfile_t write_tmp(const void *data, size_t n, mode_t mode) {
  tmpfile_t t;
  snprintf(t.path, sizeof(t.path), "/tmp/texsyn-auth-XXXXXX");
  int fd = mkstemp(t.path);
  assert_true(fd >= 0);
  assert_int_equal(write(fd, data, n), (ssize_t)n);
  assert_int_equal(fchmod(fd, mode), 0);
  close(fd);
  return t;
}

static int load_bytes(const void *data, size_t n, mode_t mode, ts_auth *a, char *err) {
  tmpfile_t t = write_tmp(data, n, mode);
  int rc = ts_auth_load(a, t.path, err);
  unlink(t.path);
  return rc;
}

#define S32 "abcdefghijklmnopqrstuvwxyz012345" /* 32 bytes, the shortest secret */

static void secret_file_strips_one_newline(void **state) {
  (void)state;
  ts_auth a;
  char err[TS_ERR_LEN];
  assert_int_equal(load_bytes(S32 "\n", 33, 0600, &a, err), 0);
  assert_int_equal(a.enabled, 1);
  assert_int_equal(a.len, 32);
  assert_memory_equal(a.secret, S32, 32);
  assert_int_equal(a.who.kind, TS_KEY_ADMIN); /* a plain secret is the admin key */
  assert_string_equal(a.who.name, "admin");
  assert_int_equal(load_bytes(S32 "\r\n", 34, 0400, &a, err), 0);
  assert_int_equal(a.len, 32);
  assert_int_equal(load_bytes(S32 "\n\n", 34, 0600, &a, err), 0);
  assert_int_equal(a.len, 33);
  assert_memory_equal(a.secret, S32 "\n", 33);
  assert_int_equal(load_bytes("a b\0c" S32, 37, 0600, &a, err), 0); /* any bytes */
  assert_int_equal(a.len, 37);
  ts_auth_clear(&a);
  assert_int_equal(a.enabled, 0);
  assert_int_equal(a.len, 0);
}

static void secret_file_refuses_fewer_than_32_bytes(void **state) {
  (void)state;
  ts_auth a;
  char err[TS_ERR_LEN];
  assert_int_equal(load_bytes(S32, 31, 0600, &a, err), TS_EINVAL);
  assert_non_null(strstr(err, "holds 31 bytes, fewer than 32"));
  assert_non_null(strstr(err, "texsyn-server --gen-secret KIND PATH"));
  assert_int_equal(load_bytes("x\n", 2, 0600, &a, err), TS_EINVAL);
  assert_int_equal(a.enabled, 0);
}

static void secret_file_refuses_group_or_world_access(void **state) {
  (void)state;
  ts_auth a;
  char err[TS_ERR_LEN];
  const mode_t modes[] = {0644, 0640, 0604, 0620, 0602, 0660};
  for (size_t i = 0; i < sizeof(modes) / sizeof(modes[0]); i++) {
    assert_int_equal(load_bytes(S32 "\n", 33, modes[i], &a, err), TS_EINVAL);
    assert_non_null(strstr(err, "chmod 600"));
    assert_int_equal(a.enabled, 0);
  }
}

#define HEX64 "00112233445566778899aabbccddeeff00112233445566778899AABBCCDDEEFF"

static void typed_keys_name_their_kind_and_owner(void **state) {
  (void)state;
  ts_auth a;
  char err[TS_ERR_LEN];
  const char *k = "texsyn:client:alice@lab-2.x_y:" HEX64 "\n";
  assert_int_equal(load_bytes(k, strlen(k), 0600, &a, err), 0);
  assert_int_equal(a.who.kind, TS_KEY_CLIENT);
  assert_string_equal(a.who.name, "alice@lab-2.x_y");
  assert_int_equal(a.len, strlen(k) - 1); /* the whole line is the secret */
  const char *bad[] = {"texsyn:boss:alice:" HEX64, "texsyn:client::" HEX64, "texsyn:client:al ice:" HEX64,
                       "texsyn:client:alice:" HEX64 "0", "texsyn:client:alice:" HEX64 "\n\n",
                       "texsyn:client:alice" HEX64, "texsyn:page:p:0g112233445566778899aabbccddeeff00112233445566778899aabbccddeeff"};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    assert_int_equal(load_bytes(bad[i], strlen(bad[i]), 0600, &a, err), TS_EINVAL);
    assert_non_null(strstr(err, "is not a texsyn key"));
  }
}

static void gen_secret_writes_a_fresh_owner_only_key_once(void **state) {
  (void)state;
  char dir[] = "/tmp/texsyn-gen-XXXXXX", path[128], path2[128], err[TS_ERR_LEN];
  assert_non_null(mkdtemp(dir));
  snprintf(path, sizeof(path), "%s/bob.key", dir);
  snprintf(path2, sizeof(path2), "%s/w", dir);
  ts_principal who;
  assert_int_equal(ts_auth_generate("client", path, &who, err), 0);
  assert_int_equal(who.kind, TS_KEY_CLIENT);
  assert_string_equal(who.name, "bob");
  struct stat sb;
  assert_int_equal(stat(path, &sb), 0);
  assert_int_equal(sb.st_mode & 07777, 0600);
  ts_auth a, b;
  assert_int_equal(ts_auth_load(&a, path, err), 0);
  assert_int_equal(a.who.kind, TS_KEY_CLIENT);
  assert_string_equal(a.who.name, "bob");
  assert_int_equal(a.len, strlen("texsyn:client:bob:") + 64);
  /* Never over an existing file: the key in use stays. */
  assert_int_equal(ts_auth_generate("client", path, &who, err), TS_EINVAL);
  assert_non_null(strstr(err, "never overwrites"));
  assert_int_equal(ts_auth_load(&b, path, err), 0);
  assert_memory_equal(a.secret, b.secret, a.len);
  /* A name given; another key is another secret. */
  assert_int_equal(ts_auth_generate("worker:pool-1", path2, &who, err), 0);
  assert_int_equal(ts_auth_load(&b, path2, err), 0);
  assert_int_equal(b.who.kind, TS_KEY_WORKER);
  assert_string_equal(b.who.name, "pool-1");
  assert_memory_not_equal(a.secret + a.len - 64, b.secret + b.len - 64, 64);
  assert_int_equal(ts_auth_generate("boss", path2, &who, err), TS_EINVAL);
  assert_non_null(strstr(err, "admin, worker, client or page"));
  assert_int_equal(ts_auth_generate("page:bad name", path2, &who, err), TS_EINVAL);
  unlink(path);
  unlink(path2);
  rmdir(dir);
}

static void secret_file_refuses_empty_oversized_missing(void **state) {
  (void)state;
  ts_auth a;
  char err[TS_ERR_LEN];
  assert_int_equal(load_bytes("", 0, 0600, &a, err), TS_EINVAL);
  assert_non_null(strstr(err, "empty"));
  assert_int_equal(load_bytes("\n", 1, 0600, &a, err), TS_EINVAL);
  static uint8_t big[TS_AUTH_SECRET_MAX + 2];
  memset(big, 'x', sizeof(big));
  big[TS_AUTH_SECRET_MAX] = '\n';
  assert_int_equal(load_bytes(big, TS_AUTH_SECRET_MAX + 1, 0600, &a, err), 0); /* the largest */
  assert_int_equal(a.len, TS_AUTH_SECRET_MAX);
  big[TS_AUTH_SECRET_MAX] = 'x';
  assert_int_equal(load_bytes(big, TS_AUTH_SECRET_MAX + 1, 0600, &a, err), TS_ETOOBIG);
  assert_int_equal(load_bytes(big, sizeof(big), 0600, &a, err), TS_ETOOBIG);
  assert_int_equal(ts_auth_load(&a, "/nonexistent/texsyn-secret", err), TS_EIO);
  assert_non_null(strstr(err, "/nonexistent/texsyn-secret"));
  assert_int_equal(ts_auth_load(&a, "/tmp", err), TS_EINVAL);
  assert_int_equal(a.enabled, 0);
}

/* ---- protected mode ------------------------------------------------------------ */

static int allowed(const ts_auth *a, int family, const char *ip) {
  struct sockaddr_storage ss;
  memset(&ss, 0, sizeof(ss));
  if (family == AF_INET) {
    struct sockaddr_in *in = (struct sockaddr_in *)&ss;
    in->sin_family = AF_INET;
    assert_int_equal(inet_pton(AF_INET, ip, &in->sin_addr), 1);
  } else {
    struct sockaddr_in6 *in6 = (struct sockaddr_in6 *)&ss;
    in6->sin6_family = AF_INET6;
    assert_int_equal(inet_pton(AF_INET6, ip, &in6->sin6_addr), 1);
  }
  char err[TS_ERR_LEN] = "";
  int rc = ts_auth_peer_allowed(a, (struct sockaddr *)&ss, err);
  if (rc != 0) assert_non_null(strstr(err, "protected mode"));
  return rc == 0;
}

static void protected_mode_admits_loopback_only(void **state) {
  (void)state;
  ts_auth none = {0};
  const ts_auth *modes[] = {NULL, &none};
  for (int m = 0; m < 2; m++) {
    assert_true(allowed(modes[m], AF_INET, "127.0.0.1"));
    assert_true(allowed(modes[m], AF_INET, "127.255.0.9"));
    assert_true(allowed(modes[m], AF_INET6, "::1"));
    assert_true(allowed(modes[m], AF_INET6, "::ffff:127.0.0.1"));
    assert_false(allowed(modes[m], AF_INET, "192.0.2.2"));
    assert_false(allowed(modes[m], AF_INET, "128.0.0.1"));
    assert_false(allowed(modes[m], AF_INET, "0.0.0.0"));
    assert_false(allowed(modes[m], AF_INET6, "fd00::2"));
    assert_false(allowed(modes[m], AF_INET6, "::ffff:10.0.0.1"));
    assert_false(allowed(modes[m], AF_INET6, "::"));
  }
  ts_auth a;
  set_secret(&a, "k");
  assert_true(allowed(&a, AF_INET, "192.0.2.2"));
  assert_true(allowed(&a, AF_INET6, "fd00::2"));
}

/* ---- the handshake over a socket pair ----------------------------------------- */

typedef struct {
  const ts_auth *auth;
  ts_conn conn;
  ts_msg_ident me, peer;
  ts_principal who;
  int rc;
  char err[TS_ERR_LEN];
} side;

static void *connect_side(void *arg) {
  side *s = arg;
  s->rc = ts_auth_connect(&s->conn, s->auth, &s->me, &s->peer, 5000, s->err);
  return NULL;
}

/* Runs both halves; the acceptor answers its own failure with an 'E' and
 * closes, as the daemons do. */
static void handshake_as(const ts_auth *acc_auth, const ts_auth *con_auth, uint8_t acc_role, uint8_t con_role,
                         side *acc, side *con) {
  int sv[2];
  assert_int_equal(socketpair(AF_UNIX, SOCK_STREAM, 0, sv), 0);
  memset(acc, 0, sizeof(*acc));
  memset(con, 0, sizeof(*con));
  acc->auth = acc_auth;
  con->auth = con_auth;
  acc->me = (ts_msg_ident){acc_role, TS_CAP_ALL, 0, 0, "acceptor"};
  con->me = (ts_msg_ident){con_role, TS_CAP_ALL, 3, 0, "connector"};
  ts_conn_init(&acc->conn, sv[0], 0, "connector");
  ts_conn_init(&con->conn, sv[1], 0, "acceptor");
  pthread_t t;
  assert_int_equal(pthread_create(&t, NULL, connect_side, con), 0);
  acc->rc = ts_auth_accept(&acc->conn, acc->auth, &acc->me, &acc->peer, &acc->who, 5000, acc->err);
  if (acc->rc != 0) {
    ts_wr w;
    ts_wr_init(&w);
    ts_msg_error_write(&w, acc->rc, acc->err);
    char err[TS_ERR_LEN];
    ts_net_send(acc->conn.fd, TS_MSG_ERROR, 0, w.buf, w.len, err);
    ts_wr_free(&w);
    shutdown(acc->conn.fd, SHUT_WR);
  }
  pthread_join(t, NULL);
  ts_conn_close(&acc->conn);
  ts_conn_close(&con->conn);
}

static void handshake(const ts_auth *acc_auth, const ts_auth *con_auth, side *acc, side *con) {
  handshake_as(acc_auth, con_auth, TS_ROLE_COORD, TS_ROLE_WORKER, acc, con);
}

static void handshake_with_the_same_secret_succeeds(void **state) {
  (void)state;
  ts_auth a;
  set_secret(&a, "shared");
  side acc, con;
  handshake(&a, &a, &acc, &con);
  assert_int_equal(acc.rc, 0);
  assert_int_equal(con.rc, 0);
  assert_int_equal(acc.peer.role, TS_ROLE_WORKER);
  assert_int_equal(acc.peer.threads, 3);
  assert_true(acc.peer.caps & TS_CAP_AUTH);
  assert_int_equal(con.peer.role, TS_ROLE_COORD);
  assert_true(con.peer.caps & TS_CAP_AUTH);
}

static void handshake_without_secrets_is_plain_identify(void **state) {
  (void)state;
  side acc, con;
  handshake(NULL, NULL, &acc, &con);
  assert_int_equal(acc.rc, 0);
  assert_int_equal(con.rc, 0);
  assert_false(acc.peer.caps & TS_CAP_AUTH);
  assert_false(con.peer.caps & TS_CAP_AUTH);
}

static void handshake_with_a_wrong_secret_fails_both_sides(void **state) {
  (void)state;
  ts_auth a, b;
  set_secret(&a, "shared");
  set_secret(&b, "Shared");
  side acc, con;
  handshake(&a, &b, &acc, &con);
  assert_int_equal(acc.rc, TS_EAUTH);
  assert_non_null(strstr(acc.err, "wrong secret"));
  assert_int_equal(con.rc, TS_EAUTH);
  assert_non_null(strstr(con.err, "wrong secret"));
}

static void handshake_without_the_required_secret_is_refused(void **state) {
  (void)state;
  ts_auth a;
  set_secret(&a, "shared");
  side acc, con;
  handshake(&a, NULL, &acc, &con);
  assert_int_equal(acc.rc, TS_EAUTH);
  assert_int_equal(con.rc, TS_EAUTH);
  assert_non_null(strstr(con.err, "requires authentication: pass --secret-file"));
  /* And the other way: a connector with a secret meets one without. */
  handshake(NULL, &a, &acc, &con);
  assert_int_equal(acc.rc, TS_EAUTH);
  assert_int_equal(con.rc, TS_EAUTH);
  assert_non_null(strstr(con.err, "no --secret-file"));
}


/* ---- principals: the coordinator's keyring ---------------------------------- */

typedef struct {
  char dir[64];
  ts_auth key[8]; /* as each holder loads it */
  int n;
} keydir;

/* Generates kind:name keys into a fresh directory, loading each. */
static void keydir_add(keydir *d, const char *spec, const char *file) {
  char path[128], err[TS_ERR_LEN];
  ts_principal who;
  snprintf(path, sizeof(path), "%s/%s", d->dir, file);
  assert_int_equal(ts_auth_generate(spec, path, &who, err), 0);
  assert_int_equal(ts_auth_load(&d->key[d->n++], path, err), 0);
}

static void keydir_make(keydir *d) {
  memset(d, 0, sizeof(*d));
  snprintf(d->dir, sizeof(d->dir), "/tmp/texsyn-keys-XXXXXX");
  assert_non_null(mkdtemp(d->dir));
  keydir_add(d, "client", "alice.key");     /* 0 */
  keydir_add(d, "client", "bob.key");       /* 1 */
  keydir_add(d, "worker", "pool.key");      /* 2 */
  keydir_add(d, "page", "prom.key");        /* 3 */
  keydir_add(d, "admin", "ops.key");        /* 4 */
}

static void keydir_remove(keydir *d) {
  char cmd[128];
  snprintf(cmd, sizeof(cmd), "rm -rf %s", d->dir);
  assert_int_equal(system(cmd), 0);
}

static void coordinator_of(ts_auth *coord, ts_keyring **ring, const keydir *d) {
  char err[TS_ERR_LEN];
  assert_int_equal(ts_keyring_create(ring, NULL, d->dir, err), 0);
  memset(coord, 0, sizeof(*coord));
  coord->enabled = 1;
  coord->ring = *ring;
}

/* Each key in its own role is let in and named; in another role it is
 * refused with the reason; a page key never opens the data plane. */
static void keyring_binds_each_key_to_its_role(void **state) {
  (void)state;
  keydir d;
  keydir_make(&d);
  ts_auth coord;
  ts_keyring *ring;
  coordinator_of(&coord, &ring, &d);
  side acc, con;
  handshake_as(&coord, &d.key[0], TS_ROLE_COORD, TS_ROLE_CLIENT, &acc, &con);
  assert_int_equal(acc.rc, 0);
  assert_int_equal(con.rc, 0);
  assert_int_equal(acc.who.kind, TS_KEY_CLIENT);
  assert_string_equal(acc.who.name, "alice");
  handshake_as(&coord, &d.key[2], TS_ROLE_COORD, TS_ROLE_WORKER, &acc, &con);
  assert_int_equal(acc.rc, 0);
  assert_int_equal(acc.who.kind, TS_KEY_WORKER);
  handshake_as(&coord, &d.key[4], TS_ROLE_COORD, TS_ROLE_WORKER, &acc, &con); /* admin: any role */
  assert_int_equal(acc.rc, 0);
  handshake_as(&coord, &d.key[2], TS_ROLE_COORD, TS_ROLE_CLIENT, &acc, &con);
  assert_int_equal(acc.rc, TS_EAUTH);
  assert_string_equal(acc.err, "refused: worker key 'pool' cannot be used by a client; a client needs a client key "
                               "(texsyn-server --gen-secret client PATH) or an admin key");
  assert_int_equal(con.rc, TS_EAUTH);
  assert_non_null(strstr(con.err, "worker key 'pool' cannot be used by a client"));
  handshake_as(&coord, &d.key[0], TS_ROLE_COORD, TS_ROLE_WORKER, &acc, &con);
  assert_int_equal(acc.rc, TS_EAUTH);
  assert_non_null(strstr(acc.err, "client key 'alice' cannot be used by a worker"));
  handshake_as(&coord, &d.key[3], TS_ROLE_COORD, TS_ROLE_CLIENT, &acc, &con);
  assert_int_equal(acc.rc, TS_EAUTH);
  assert_string_equal(acc.err, "refused: page key 'prom' opens the operations page only, never the data plane");
  /* A client posing as the coordinator to the coordinator is no admin. */
  handshake_as(&coord, &d.key[0], TS_ROLE_COORD, TS_ROLE_COORD, &acc, &con);
  assert_int_equal(acc.rc, TS_EAUTH);
  ts_keyring_destroy(ring);
  keydir_remove(&d);
}

/* An unknown name and a wrong secret under a known one read the same to
 * the peer. */
static void keyring_refuses_unknown_names_like_wrong_secrets(void **state) {
  (void)state;
  keydir d;
  keydir_make(&d);
  ts_auth coord, forged = d.key[0], stranger = d.key[0];
  ts_keyring *ring;
  coordinator_of(&coord, &ring, &d);
  forged.secret[forged.len - 1] ^= 1;
  snprintf(stranger.who.name, sizeof(stranger.who.name), "zed");
  side acc, con;
  handshake_as(&coord, &forged, TS_ROLE_COORD, TS_ROLE_CLIENT, &acc, &con);
  assert_int_equal(acc.rc, TS_EAUTH);
  char want[TS_ERR_LEN];
  snprintf(want, sizeof(want), "%s", acc.err);
  assert_string_equal(want, "authentication failed: wrong secret, or no client key 'alice' here (the coordinator's "
                            "--keys directory must hold that key's file)");
  handshake_as(&coord, &stranger, TS_ROLE_COORD, TS_ROLE_CLIENT, &acc, &con);
  assert_int_equal(acc.rc, TS_EAUTH);
  assert_non_null(strstr(acc.err, "wrong secret, or no client key 'zed' here"));
  ts_keyring_destroy(ring);
  keydir_remove(&d);
}

/* A worker started with --listen names its key; the coordinator proves
 * itself with that key from its ring, and cannot without it. */
static void coordinator_proves_itself_with_the_workers_key(void **state) {
  (void)state;
  keydir d;
  keydir_make(&d);
  ts_auth coord;
  ts_keyring *ring;
  coordinator_of(&coord, &ring, &d);
  side acc, con;
  handshake_as(&d.key[2], &coord, TS_ROLE_WORKER, TS_ROLE_COORD, &acc, &con);
  assert_int_equal(acc.rc, 0);
  assert_int_equal(con.rc, 0);
  assert_int_equal(acc.who.kind, TS_KEY_WORKER);
  /* A client key given to a worker: the coordinator will not use it. */
  handshake_as(&d.key[1], &coord, TS_ROLE_WORKER, TS_ROLE_COORD, &acc, &con);
  assert_int_equal(con.rc, TS_EAUTH);
  assert_non_null(strstr(con.err, "client key 'bob' cannot be used by a server"));
  /* A worker key the coordinator does not hold. */
  keydir other;
  keydir_make(&other);
  handshake_as(&other.key[2], &coord, TS_ROLE_WORKER, TS_ROLE_COORD, &acc, &con); /* same name, other secret */
  assert_int_equal(acc.rc, TS_EAUTH);
  assert_int_equal(con.rc, TS_EAUTH);
  assert_non_null(strstr(con.err, "wrong secret"));
  keydir_add(&other, "worker:elsewhere", "elsewhere.key");
  handshake_as(&other.key[other.n - 1], &coord, TS_ROLE_WORKER, TS_ROLE_COORD, &acc, &con);
  assert_int_equal(con.rc, TS_EAUTH);
  assert_string_equal(con.err, "authentication failed: acceptor uses worker key 'elsewhere', which is not in this "
                               "coordinator's --keys or --secret-file");
  ts_keyring_destroy(ring);
  keydir_remove(&d);
  keydir_remove(&other);
}

/* Rotation: an old and a new key of one name both work until the old
 * file is removed and the ring reloaded; a failed reload keeps the keys. */
static void keyring_rotates_without_a_restart(void **state) {
  (void)state;
  keydir d;
  keydir_make(&d);
  char old_path[128], new_path[128], err[TS_ERR_LEN];
  snprintf(old_path, sizeof(old_path), "%s/alice.key", d.dir);
  snprintf(new_path, sizeof(new_path), "%s/alice-2.key", d.dir);
  ts_principal who;
  assert_int_equal(ts_auth_generate("client:alice", new_path, &who, err), 0);
  ts_auth fresh;
  assert_int_equal(ts_auth_load(&fresh, new_path, err), 0);
  ts_auth coord;
  ts_keyring *ring;
  coordinator_of(&coord, &ring, &d);
  side acc, con;
  handshake_as(&coord, &d.key[0], TS_ROLE_COORD, TS_ROLE_CLIENT, &acc, &con);
  assert_int_equal(acc.rc, 0);
  handshake_as(&coord, &fresh, TS_ROLE_COORD, TS_ROLE_CLIENT, &acc, &con);
  assert_int_equal(acc.rc, 0);
  assert_int_equal(unlink(old_path), 0);
  assert_int_equal(ts_keyring_reload(ring, err), 0);
  handshake_as(&coord, &d.key[0], TS_ROLE_COORD, TS_ROLE_CLIENT, &acc, &con);
  assert_int_equal(acc.rc, TS_EAUTH);
  handshake_as(&coord, &fresh, TS_ROLE_COORD, TS_ROLE_CLIENT, &acc, &con);
  assert_int_equal(acc.rc, 0);
  /* A plain secret among the keys: the reload fails, the keys stay. */
  char plain[128];
  snprintf(plain, sizeof(plain), "%s/plain.key", d.dir);
  tmpfile_t t = write_tmp(S32 "\n", 33, 0600);
  assert_int_equal(rename(t.path, plain), 0);
  assert_int_equal(ts_keyring_reload(ring, err), TS_EINVAL);
  assert_non_null(strstr(err, "is not a typed key"));
  handshake_as(&coord, &fresh, TS_ROLE_COORD, TS_ROLE_CLIENT, &acc, &con);
  assert_int_equal(acc.rc, 0);
  uint32_t n[5];
  ts_keyring_counts(ring, n);
  assert_int_equal(n[TS_KEY_CLIENT], 2); /* bob and the new alice */
  ts_keyring_destroy(ring);
  keydir_remove(&d);
}

/* The page's check: a page or admin key as the whole token, nothing else. */
static void keyring_matches_page_tokens(void **state) {
  (void)state;
  keydir d;
  keydir_make(&d);
  ts_auth coord;
  ts_keyring *ring;
  coordinator_of(&coord, &ring, &d);
  unsigned page = (1u << TS_KEY_PAGE) | (1u << TS_KEY_ADMIN);
  ts_principal who;
  assert_true(ts_keyring_match(ring, d.key[3].secret, d.key[3].len, page, &who));
  assert_string_equal(who.name, "prom");
  assert_true(ts_keyring_match(ring, d.key[4].secret, d.key[4].len, page, &who));
  assert_int_equal(who.kind, TS_KEY_ADMIN);
  assert_false(ts_keyring_match(ring, d.key[0].secret, d.key[0].len, page, &who)); /* a client key */
  assert_false(ts_keyring_match(ring, d.key[2].secret, d.key[2].len, page, &who)); /* a worker key */
  assert_false(ts_keyring_match(ring, d.key[3].secret, d.key[3].len - 1, page, &who));
  ts_keyring_destroy(ring);
  keydir_remove(&d);
}

static void keyring_refuses_an_empty_or_missing_directory(void **state) {
  (void)state;
  char dir[] = "/tmp/texsyn-nokeys-XXXXXX", err[TS_ERR_LEN];
  assert_non_null(mkdtemp(dir));
  ts_keyring *ring;
  assert_int_equal(ts_keyring_create(&ring, NULL, dir, err), TS_EINVAL);
  assert_non_null(strstr(err, "holds no *.key file"));
  rmdir(dir);
  assert_int_equal(ts_keyring_create(&ring, NULL, dir, err), TS_EIO);
  assert_non_null(strstr(err, "cannot read the --keys directory"));
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test_setup(hmac_matches_rfc4231, setup),
    cmocka_unit_test_setup(proof_matches_documented_transcript, setup),
    cmocka_unit_test_setup(verify_refuses_every_flipped_bit, setup),
    cmocka_unit_test_setup(proof_is_bound_to_its_transcript, setup),
    cmocka_unit_test_setup(secret_file_strips_one_newline, setup),
    cmocka_unit_test_setup(secret_file_refuses_fewer_than_32_bytes, setup),
    cmocka_unit_test_setup(secret_file_refuses_group_or_world_access, setup),
    cmocka_unit_test_setup(typed_keys_name_their_kind_and_owner, setup),
    cmocka_unit_test_setup(gen_secret_writes_a_fresh_owner_only_key_once, setup),
    cmocka_unit_test_setup(secret_file_refuses_empty_oversized_missing, setup),
    cmocka_unit_test_setup(protected_mode_admits_loopback_only, setup),
    cmocka_unit_test_setup(handshake_with_the_same_secret_succeeds, setup),
    cmocka_unit_test_setup(handshake_without_secrets_is_plain_identify, setup),
    cmocka_unit_test_setup(handshake_with_a_wrong_secret_fails_both_sides, setup),
    cmocka_unit_test_setup(handshake_without_the_required_secret_is_refused, setup),
    cmocka_unit_test_setup(keyring_binds_each_key_to_its_role, setup),
    cmocka_unit_test_setup(keyring_refuses_unknown_names_like_wrong_secrets, setup),
    cmocka_unit_test_setup(coordinator_proves_itself_with_the_workers_key, setup),
    cmocka_unit_test_setup(keyring_rotates_without_a_restart, setup),
    cmocka_unit_test_setup(keyring_matches_page_tokens, setup),
    cmocka_unit_test_setup(keyring_refuses_an_empty_or_missing_directory, setup),
};

TS_TEST_MAIN(tests)
