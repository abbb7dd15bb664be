/* test_seal.c - sealed frames (proto/seal.h): what goes in comes out, and
 * every frame tampered with, replayed, reordered, dropped or truncated is
 * refused with its reason; over a connection too, and with the keys a real
 * handshake derives. */
#include <pthread.h>
#include <sodium.h>
#include <sys/socket.h>

#include "auth.h"
#include "error.h"
#include "net.h"
#include "seal.h"
#include "ts_test.h"

static int setup(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  return ts_auth_init(err);
}

/* Two ends: a seals with k1 and opens with k2, b the other way round. */
typedef struct {
  ts_seal a, b;
} pair;

static void pair_init(pair *p) {
  uint8_t k1[TS_SEAL_KEY], k2[TS_SEAL_KEY];
  memset(k1, 0x11, sizeof(k1));
  memset(k2, 0x22, sizeof(k2));
  assert_int_equal(ts_seal_init(&p->a, k1, k2), 0);
  assert_int_equal(ts_seal_init(&p->b, k2, k1), 0);
}

static void pair_free(pair *p) {
  ts_seal_free(&p->a);
  ts_seal_free(&p->b);
}

/* Seals n plain bytes as one sealed frame into a fresh buffer. */
static void seal_bytes(ts_seal *s, ts_wr *out, const void *p, size_t n) {
  char err[TS_ERR_LEN];
  ts_wr_init(out);
  assert_int_equal(ts_seal_append(s, out, p, n, err), 0);
}

/* The sealed frame at the start of bytes b (whole, as written). */
static ts_frame frame_at(const uint8_t *b) {
  ts_frame f;
  f.type = b[3];
  f.len = (uint32_t)ts_get_le(b + 4, 4);
  f.id = (uint32_t)ts_get_le(b + 8, 4);
  f.payload = b + TS_FRAME_HEADER;
  return f;
}

static int open_one(ts_seal *s, const ts_frame *f, char *err) {
  const uint8_t *plain;
  size_t n;
  return ts_seal_open(s, f, &plain, &n, err);
}

static void round_trip_in_any_sizes(void **state) {
  (void)state;
  pair p;
  pair_init(&p);
  size_t total = 3 * TS_SEAL_CHUNK + 777;
  uint8_t *msg = malloc(total);
  for (size_t i = 0; i < total; i++) msg[i] = (uint8_t)(i * 7 + 3);
  ts_wr w;
  seal_bytes(&p.a, &w, msg, total);
  /* 4 sealed frames, each at most a chunk, the last with the rest. */
  assert_int_equal(w.len, total + 4 * (TS_FRAME_HEADER + TS_SEAL_TAG));
  uint8_t *got = malloc(total);
  size_t off = 0, at = 0;
  char err[TS_ERR_LEN];
  for (uint32_t k = 0; k < 4; k++) {
    ts_frame f = frame_at(w.buf + at);
    assert_int_equal(f.type, TS_FRAME_SEALED);
    assert_int_equal(f.id, k);
    const uint8_t *plain;
    size_t n;
    assert_int_equal(ts_seal_open(&p.b, &f, &plain, &n, err), 1);
    assert_int_equal(n, k < 3 ? TS_SEAL_CHUNK : 777);
    memcpy(got + off, plain, n);
    off += n;
    at += TS_FRAME_HEADER + f.len;
  }
  assert_int_equal(off, total);
  assert_memory_equal(got, msg, total);
  /* Nothing of the plain bytes shows: no 32-byte run of them anywhere. */
  assert_null(memmem(w.buf, w.len, msg + 1000, 32));
  free(got);
  free(msg);
  ts_wr_free(&w);
  pair_free(&p);
}

static void every_altered_byte_is_detected(void **state) {
  (void)state;
  const char msg[] = "TS\x07V a query batch, or anything else";
  /* The type, the id, every payload and tag byte. Magic and version are
   * the frame reader's to refuse (test_frame); a changed length makes it
   * cut another frame (a_truncated_frame_is_detected). */
  for (size_t pos = 3; pos < TS_FRAME_HEADER + sizeof(msg) + TS_SEAL_TAG; pos++) {
    if (pos >= 4 && pos < 8) continue;
    pair p;
    pair_init(&p);
    ts_wr w;
    seal_bytes(&p.a, &w, msg, sizeof(msg));
    w.buf[pos] ^= 0x01;
    ts_frame f = frame_at(w.buf);
    char err[TS_ERR_LEN] = "";
    assert_int_equal(open_one(&p.b, &f, err), TS_EPROTO);
    if (pos == 3) assert_non_null(strstr(err, "a plain"));
    else if (pos < TS_FRAME_HEADER) assert_non_null(strstr(err, "where 0 was due"));
    else assert_non_null(strstr(err, "sealed frame 0 failed authentication (altered"));
    ts_wr_free(&w);
    pair_free(&p);
  }
}

static void a_truncated_frame_is_detected(void **state) {
  (void)state;
  pair p;
  pair_init(&p);
  const char msg[] = "a reply of some length";
  ts_wr w;
  seal_bytes(&p.a, &w, msg, sizeof(msg));
  ts_frame f = frame_at(w.buf);
  char err[TS_ERR_LEN];
  /* Shorter, with a header that says so: the tag is not where it was. */
  f.len -= 1;
  assert_int_equal(open_one(&p.b, &f, err), TS_EPROTO);
  assert_non_null(strstr(err, "failed authentication"));
  /* So short that no tag fits. */
  f.len = TS_SEAL_TAG;
  assert_int_equal(open_one(&p.b, &f, err), TS_EPROTO);
  assert_non_null(strstr(err, "too short to hold its tag (truncated)"));
  /* Still the one due after both: the honest frame opens. */
  f = frame_at(w.buf);
  assert_int_equal(open_one(&p.b, &f, err), 1);
  ts_wr_free(&w);
  pair_free(&p);
}

/* Three frames sealed in a row; their bytes kept apart. */
static void seal_three(ts_seal *s, ts_wr w[3]) {
  const char *msgs[3] = {"first", "second", "third"};
  for (int i = 0; i < 3; i++) seal_bytes(s, &w[i], msgs[i], strlen(msgs[i]));
}

static void free_three(ts_wr w[3]) {
  for (int i = 0; i < 3; i++) ts_wr_free(&w[i]);
}

static void a_replayed_frame_is_detected(void **state) {
  (void)state;
  pair p;
  pair_init(&p);
  ts_wr w[3];
  seal_three(&p.a, w);
  char err[TS_ERR_LEN];
  ts_frame f0 = frame_at(w[0].buf), f1 = frame_at(w[1].buf);
  assert_int_equal(open_one(&p.b, &f0, err), 1);
  assert_int_equal(open_one(&p.b, &f1, err), 1);
  assert_int_equal(open_one(&p.b, &f0, err), TS_EPROTO);
  assert_string_equal(err, "sealed link: sealed frame 0 arrived again where 2 was due (replayed or reordered)");
  /* A replay with its id rewritten to the one due fails its tag. */
  uint8_t copy[64];
  memcpy(copy, w[0].buf, w[0].len);
  ts_put_le(copy + 8, 2, 4);
  ts_frame forged = frame_at(copy);
  assert_int_equal(open_one(&p.b, &forged, err), TS_EPROTO);
  assert_non_null(strstr(err, "sealed frame 2 failed authentication"));
  free_three(w);
  pair_free(&p);
}

static void a_reordered_frame_is_detected(void **state) {
  (void)state;
  pair p;
  pair_init(&p);
  ts_wr w[3];
  seal_three(&p.a, w);
  char err[TS_ERR_LEN];
  ts_frame f0 = frame_at(w[0].buf), f2 = frame_at(w[2].buf), f1 = frame_at(w[1].buf);
  assert_int_equal(open_one(&p.b, &f0, err), 1);
  assert_int_equal(open_one(&p.b, &f2, err), TS_EPROTO);
  assert_string_equal(err, "sealed link: sealed frame 2 arrived where 1 was due (1 dropped, or reordered)");
  /* Renumbered to look due, it still fails: the counter is the nonce. */
  uint8_t copy[64];
  memcpy(copy, w[2].buf, w[2].len);
  ts_put_le(copy + 8, 1, 4);
  ts_frame forged = frame_at(copy);
  assert_int_equal(open_one(&p.b, &forged, err), TS_EPROTO);
  assert_non_null(strstr(err, "sealed frame 1 failed authentication"));
  assert_int_equal(open_one(&p.b, &f1, err), 1);
  free_three(w);
  pair_free(&p);
}

static void a_dropped_frame_is_detected(void **state) {
  (void)state;
  pair p;
  pair_init(&p);
  ts_wr w[3];
  seal_three(&p.a, w);
  char err[TS_ERR_LEN];
  ts_frame f0 = frame_at(w[0].buf), f2 = frame_at(w[2].buf);
  assert_int_equal(open_one(&p.b, &f0, err), 1);
  /* Frame 1 never comes: frame 2 is refused, not taken in its place. */
  assert_int_equal(open_one(&p.b, &f2, err), TS_EPROTO);
  assert_string_equal(err, "sealed link: sealed frame 2 arrived where 1 was due (1 dropped, or reordered)");
  free_three(w);
  pair_free(&p);
}

static void a_frame_reflected_back_fails(void **state) {
  (void)state;
  pair p;
  pair_init(&p);
  ts_wr w;
  seal_bytes(&p.a, &w, "mine", 4);
  ts_frame f = frame_at(w.buf);
  char err[TS_ERR_LEN];
  /* The other direction has its own key. */
  assert_int_equal(open_one(&p.a, &f, err), TS_EPROTO);
  assert_non_null(strstr(err, "failed authentication"));
  ts_wr_free(&w);
  pair_free(&p);
}

/* ---- over a connection ---------------------------------------------------- */

typedef struct {
  ts_conn a, b;
} link_pair;

static void link_init(link_pair *l) {
  int sv[2];
  assert_int_equal(socketpair(AF_UNIX, SOCK_STREAM, 0, sv), 0);
  ts_conn_init(&l->a, sv[0], 0, "b"); /* each named by its peer */
  ts_conn_init(&l->b, sv[1], 0, "a");
  uint8_t k1[TS_SEAL_KEY], k2[TS_SEAL_KEY];
  randombytes_buf(k1, sizeof(k1));
  randombytes_buf(k2, sizeof(k2));
  char err[TS_ERR_LEN];
  assert_int_equal(ts_conn_start_seal(&l->a, k1, k2, err), 0);
  assert_int_equal(ts_conn_start_seal(&l->b, k2, k1, err), 0);
}

static void link_free(link_pair *l) {
  ts_conn_close(&l->a);
  ts_conn_close(&l->b);
}

typedef struct {
  ts_conn *c;
  const uint8_t *p;
  size_t n;
} sender;

static void *send_big(void *arg) {
  sender *s = arg;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_conn_send(s->c, 'N', 77, s->p, s->n, err), 0);
  return NULL;
}

static void frames_cross_a_sealed_connection_whole(void **state) {
  (void)state;
  link_pair l;
  link_init(&l);
  char err[TS_ERR_LEN];
  size_t n = 300000;
  uint8_t *big = malloc(n);
  for (size_t i = 0; i < n; i++) big[i] = (uint8_t)(i ^ (i >> 9));
  sender s = {&l.a, big, n};
  pthread_t t;
  assert_int_equal(pthread_create(&t, NULL, send_big, &s), 0);
  ts_frame f;
  assert_int_equal(ts_conn_recv(&l.b, &f, 5000, err), 1);
  pthread_join(t, NULL);
  assert_int_equal(f.type, 'N');
  assert_int_equal(f.id, 77);
  assert_int_equal(f.len, n);
  assert_memory_equal(f.payload, big, n);
  assert_int_equal(ts_conn_send(&l.b, 'H', 78, NULL, 0, err), 0);
  assert_int_equal(ts_conn_recv(&l.a, &f, 5000, err), 1);
  assert_int_equal(f.type, 'H');
  assert_int_equal(f.len, 0);
  free(big);
  link_free(&l);
}

static void an_injected_plain_frame_ends_the_connection(void **state) {
  (void)state;
  link_pair l;
  link_init(&l);
  char err[TS_ERR_LEN];
  ts_frame f;
  assert_int_equal(ts_conn_send(&l.a, 'W', 1, "x", 1, err), 0);
  assert_int_equal(ts_conn_recv(&l.b, &f, 5000, err), 1);
  /* What a relay without the keys can send: a well-formed plain frame. */
  assert_int_equal(ts_net_send(l.a.fd, 'X', 2, "12345678", 8, err), 0);
  assert_int_equal(ts_conn_recv(&l.b, &f, 5000, err), TS_EPROTO);
  assert_string_equal(err, "a: sealed link: a plain 'X' frame where sealed frame 1 was due (injected?)");
  link_free(&l);
}

static void a_connection_cut_inside_a_sealed_frame_says_truncated(void **state) {
  (void)state;
  link_pair l;
  link_init(&l);
  char err[TS_ERR_LEN];
  ts_wr w;
  ts_wr_init(&w);
  assert_int_equal(ts_seal_append(l.a.seal, &w, "0123456789", 10, err), 0);
  assert_int_equal(write(l.a.fd, w.buf, w.len - 5), (ssize_t)(w.len - 5));
  shutdown(l.a.fd, SHUT_WR);
  ts_frame f;
  assert_int_equal(ts_conn_recv(&l.b, &f, 5000, err), TS_ECONN);
  assert_string_equal(err, "a closed the connection inside sealed frame 0 (truncated)");
  ts_wr_free(&w);
  link_free(&l);
}

/* ---- keys from the handshake ---------------------------------------------- */

static void session_keys_pair_up_and_follow_the_transcript(void **state) {
  (void)state;
  ts_auth a;
  memset(&a, 0, sizeof(a));
  a.enabled = 1;
  a.len = 6;
  memcpy(a.secret, "shared", 6);
  uint8_t t[TS_AUTH_TRANSCRIPT];
  memset(t, 5, sizeof(t));
  uint8_t ctx[TS_SEAL_KEY], crx[TS_SEAL_KEY], atx[TS_SEAL_KEY], arx[TS_SEAL_KEY];
  ts_auth_session_keys(&a, t, 1, ctx, crx);
  ts_auth_session_keys(&a, t, 0, atx, arx);
  assert_memory_equal(ctx, arx, TS_SEAL_KEY);
  assert_memory_equal(crx, atx, TS_SEAL_KEY);
  assert_memory_not_equal(ctx, crx, TS_SEAL_KEY);
  /* One bit of the transcript (an 'I' frame's capabilities, say), or of
   * the secret, and both keys change. */
  uint8_t tx2[TS_SEAL_KEY], rx2[TS_SEAL_KEY];
  t[17] ^= 4;
  ts_auth_session_keys(&a, t, 1, tx2, rx2);
  assert_memory_not_equal(ctx, tx2, TS_SEAL_KEY);
  assert_memory_not_equal(crx, rx2, TS_SEAL_KEY);
  t[17] ^= 4;
  a.secret[0] ^= 1;
  ts_auth_session_keys(&a, t, 1, tx2, rx2);
  assert_memory_not_equal(ctx, tx2, TS_SEAL_KEY);
}

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
  if (s->rc == 0) s->rc = ts_conn_send(&s->conn, 'P', 9, "pool?", 5, s->err);
  return NULL;
}

static void a_handshake_with_a_secret_seals_the_connection(void **state) {
  (void)state;
  ts_auth a;
  memset(&a, 0, sizeof(a));
  a.enabled = 1;
  a.len = 6;
  memcpy(a.secret, "shared", 6);
  a.who = (ts_principal){TS_KEY_ADMIN, "admin"};
  int sv[2];
  assert_int_equal(socketpair(AF_UNIX, SOCK_STREAM, 0, sv), 0);
  side acc = {&a, {0}, {TS_ROLE_COORD, TS_CAP_ALL, 0, 0, "coordinator", 0}, {0}, 0, ""};
  side con = {&a, {0}, {TS_ROLE_CLIENT, TS_CAP_ALL, 0, 0, "client", 0}, {0}, 0, ""};
  ts_conn_init(&acc.conn, sv[0], 0, "connector");
  ts_conn_init(&con.conn, sv[1], 0, "acceptor");
  pthread_t t;
  assert_int_equal(pthread_create(&t, NULL, connect_side, &con), 0);
  acc.rc = ts_auth_accept(&acc.conn, acc.auth, &acc.me, &acc.peer, NULL, 5000, acc.err);
  assert_int_equal(acc.rc, 0);
  assert_non_null(acc.conn.seal);
  ts_frame f;
  assert_int_equal(ts_conn_recv(&acc.conn, &f, 5000, acc.err), 1);
  pthread_join(t, NULL);
  assert_int_equal(con.rc, 0);
  assert_non_null(con.conn.seal);
  assert_int_equal(f.type, 'P');
  assert_int_equal(f.len, 5);
  assert_memory_equal(f.payload, "pool?", 5);
  ts_conn_close(&acc.conn);
  ts_conn_close(&con.conn);
}

static void a_handshake_without_a_secret_stays_plain(void **state) {
  (void)state;
  int sv[2];
  assert_int_equal(socketpair(AF_UNIX, SOCK_STREAM, 0, sv), 0);
  side acc = {NULL, {0}, {TS_ROLE_COORD, TS_CAP_ALL, 0, 0, "coordinator", 0}, {0}, 0, ""};
  side con = {NULL, {0}, {TS_ROLE_CLIENT, TS_CAP_ALL, 0, 0, "client", 0}, {0}, 0, ""};
  ts_conn_init(&acc.conn, sv[0], 0, "connector");
  ts_conn_init(&con.conn, sv[1], 0, "acceptor");
  pthread_t t;
  assert_int_equal(pthread_create(&t, NULL, connect_side, &con), 0);
  assert_int_equal(ts_auth_accept(&acc.conn, NULL, &acc.me, &acc.peer, NULL, 5000, acc.err), 0);
  ts_frame f;
  assert_int_equal(ts_conn_recv(&acc.conn, &f, 5000, acc.err), 1);
  pthread_join(t, NULL);
  assert_null(acc.conn.seal);
  assert_null(con.conn.seal);
  assert_int_equal(f.type, 'P');
  ts_conn_close(&acc.conn);
  ts_conn_close(&con.conn);
}

static const struct CMUnitTest tests[] = {
  cmocka_unit_test_setup(round_trip_in_any_sizes, setup),
  cmocka_unit_test_setup(every_altered_byte_is_detected, setup),
  cmocka_unit_test_setup(a_truncated_frame_is_detected, setup),
  cmocka_unit_test_setup(a_replayed_frame_is_detected, setup),
  cmocka_unit_test_setup(a_reordered_frame_is_detected, setup),
  cmocka_unit_test_setup(a_dropped_frame_is_detected, setup),
  cmocka_unit_test_setup(a_frame_reflected_back_fails, setup),
  cmocka_unit_test_setup(frames_cross_a_sealed_connection_whole, setup),
  cmocka_unit_test_setup(an_injected_plain_frame_ends_the_connection, setup),
  cmocka_unit_test_setup(a_connection_cut_inside_a_sealed_frame_says_truncated, setup),
  cmocka_unit_test_setup(session_keys_pair_up_and_follow_the_transcript, setup),
  cmocka_unit_test_setup(a_handshake_with_a_secret_seals_the_connection, setup),
  cmocka_unit_test_setup(a_handshake_without_a_secret_stays_plain, setup),
};

TS_TEST_MAIN(tests)
