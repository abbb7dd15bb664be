/* test_auth.c - connection authentication (proto/auth.c): HMAC against
 * published and independently computed vectors, proofs that fail on any
 * flipped bit and are bound to their transcript (direction, roles, both
 * nonces), secret-file checks, the protected-mode peer check, and both
 * halves of the handshake over a socket pair. */
#include <arpa/inet.h>
#include <netinet/in.h>
#include <pthread.h>
#include <stdio.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <unistd.h>

#include "auth.h"
#include "error.h"
#include "ts_test.h"

static void set_secret(ts_auth *a, const char *s) {
  memset(a, 0, sizeof(*a));
  a->len = strlen(s);
  memcpy(a->secret, s, a->len);
  a->enabled = 1;
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
 * HMAC(key, "texsyn-auth-v1" || by || connector role || acceptor role ||
 * challenge || nonce). */
static void proof_matches_documented_transcript(void **state) {
  (void)state;
  ts_auth a;
  set_secret(&a, "texsyn unit-test secret");
  nonces n = counting_nonces();
  uint8_t mac[TS_AUTH_MAC];
  char h[2 * TS_AUTH_MAC + 1];
  ts_auth_mac(&a, TS_AUTH_BY_CONNECTOR, TS_ROLE_CLIENT, TS_ROLE_COORD, n.challenge, n.nonce, mac);
  hex(mac, sizeof(mac), h);
  assert_string_equal(h, "22b62b9fcac6cb39322d177d6936b9abbdfeb83bf1c19395386d077287e891b4");
  ts_auth_mac(&a, TS_AUTH_BY_ACCEPTOR, TS_ROLE_CLIENT, TS_ROLE_COORD, n.challenge, n.nonce, mac);
  hex(mac, sizeof(mac), h);
  assert_string_equal(h, "7809182d1db73efadde4744c45784d20626de0962656f2392fa4fad89e137dc1");
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

static void secret_file_strips_one_newline(void **state) {
  (void)state;
  ts_auth a;
  char err[TS_ERR_LEN];
  assert_int_equal(load_bytes("abc\n", 4, 0600, &a, err), 0);
  assert_int_equal(a.enabled, 1);
  assert_int_equal(a.len, 3);
  assert_memory_equal(a.secret, "abc", 3);
  assert_int_equal(load_bytes("abc\r\n", 5, 0400, &a, err), 0);
  assert_int_equal(a.len, 3);
  assert_int_equal(load_bytes("abc\n\n", 5, 0600, &a, err), 0);
  assert_int_equal(a.len, 4);
  assert_memory_equal(a.secret, "abc\n", 4);
  assert_int_equal(load_bytes("a b\0c", 5, 0600, &a, err), 0); /* any bytes */
  assert_int_equal(a.len, 5);
  ts_auth_clear(&a);
  assert_int_equal(a.enabled, 0);
  assert_int_equal(a.len, 0);
}

static void secret_file_refuses_group_or_world_access(void **state) {
  (void)state;
  ts_auth a;
  char err[TS_ERR_LEN];
  const mode_t modes[] = {0644, 0640, 0604, 0620, 0602, 0660};
  for (size_t i = 0; i < sizeof(modes) / sizeof(modes[0]); i++) {
    assert_int_equal(load_bytes("abc\n", 4, modes[i], &a, err), TS_EINVAL);
    assert_non_null(strstr(err, "chmod 600"));
    assert_int_equal(a.enabled, 0);
  }
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
static void handshake(const ts_auth *acc_auth, const ts_auth *con_auth, side *acc, side *con) {
  int sv[2];
  assert_int_equal(socketpair(AF_UNIX, SOCK_STREAM, 0, sv), 0);
  memset(acc, 0, sizeof(*acc));
  memset(con, 0, sizeof(*con));
  acc->auth = acc_auth;
  con->auth = con_auth;
  acc->me = (ts_msg_ident){TS_ROLE_COORD, TS_CAP_ALL, 0, 0, "coordinator"};
  con->me = (ts_msg_ident){TS_ROLE_WORKER, TS_CAP_ALL, 3, 0, "worker"};
  ts_conn_init(&acc->conn, sv[0], 0, "connector");
  ts_conn_init(&con->conn, sv[1], 0, "acceptor");
  pthread_t t;
  assert_int_equal(pthread_create(&t, NULL, connect_side, con), 0);
  acc->rc = ts_auth_accept(&acc->conn, acc->auth, &acc->me, &acc->peer, 5000, acc->err);
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

static const struct CMUnitTest tests[] = {
    cmocka_unit_test_setup(hmac_matches_rfc4231, setup),
    cmocka_unit_test_setup(proof_matches_documented_transcript, setup),
    cmocka_unit_test_setup(verify_refuses_every_flipped_bit, setup),
    cmocka_unit_test_setup(proof_is_bound_to_its_transcript, setup),
    cmocka_unit_test_setup(secret_file_strips_one_newline, setup),
    cmocka_unit_test_setup(secret_file_refuses_group_or_world_access, setup),
    cmocka_unit_test_setup(secret_file_refuses_empty_oversized_missing, setup),
    cmocka_unit_test_setup(protected_mode_admits_loopback_only, setup),
    cmocka_unit_test_setup(handshake_with_the_same_secret_succeeds, setup),
    cmocka_unit_test_setup(handshake_without_secrets_is_plain_identify, setup),
    cmocka_unit_test_setup(handshake_with_a_wrong_secret_fails_both_sides, setup),
    cmocka_unit_test_setup(handshake_without_the_required_secret_is_refused, setup),
};

TS_TEST_MAIN(tests)
