/* test_gate.c - the door before authentication (proto/gate.h): pending
 * connection starts counted per address, the oldest evicted past a limit
 * (its socket shut down, which its peer sees as the end), a left one no
 * longer counted, and addresses keyed as IPv4 or IPv6 /64. */
#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include "gate.h"
#include "ts_test.h"

static struct sockaddr_storage v4(uint32_t host_order) {
  struct sockaddr_storage ss = {0};
  struct sockaddr_in *in = (struct sockaddr_in *)&ss;
  in->sin_family = AF_INET;
  in->sin_addr.s_addr = htonl(host_order);
  return ss;
}

typedef struct {
  int ours, theirs; /* a socketpair: the gate holds ours */
} conn;

static conn open_conn(void) {
  int sv[2];
  assert_int_equal(socketpair(AF_UNIX, SOCK_STREAM, 0, sv), 0);
  return (conn){sv[0], sv[1]};
}

/* Whether the gate shut the connection down: its peer reads the end. */
static int evicted(const conn *c) {
  char b;
  return recv(c->theirs, &b, 1, MSG_DONTWAIT) == 0;
}

static void close_conn(conn *c) {
  close(c->ours);
  close(c->theirs);
}

static void one_address_past_its_limit_loses_its_oldest(void **state) {
  (void)state;
  ts_gate g;
  ts_gate_init(&g, "test port", NULL);
  conn c[TS_GATE_PER_ADDR + 2], other = open_conn();
  struct sockaddr_storage a = v4(0x0A000001), b = v4(0x0A000002);
  ts_gate_enter(&g, other.ours, (struct sockaddr *)&b);
  for (int i = 0; i < TS_GATE_PER_ADDR; i++) {
    c[i] = open_conn();
    ts_gate_enter(&g, c[i].ours, (struct sockaddr *)&a);
  }
  for (int i = 0; i < TS_GATE_PER_ADDR; i++) assert_false(evicted(&c[i]));
  c[TS_GATE_PER_ADDR] = open_conn();
  ts_gate_enter(&g, c[TS_GATE_PER_ADDR].ours, (struct sockaddr *)&a);
  assert_true(evicted(&c[0]));
  for (int i = 1; i <= TS_GATE_PER_ADDR; i++) assert_false(evicted(&c[i]));
  assert_false(evicted(&other)); /* another address keeps its start */
  /* One that authenticated leaves: a new one takes its place, no eviction. */
  ts_gate_leave(&g, c[1].ours);
  c[TS_GATE_PER_ADDR + 1] = open_conn();
  ts_gate_enter(&g, c[TS_GATE_PER_ADDR + 1].ours, (struct sockaddr *)&a);
  for (int i = 1; i <= TS_GATE_PER_ADDR + 1; i++) assert_false(evicted(&c[i]));
  for (int i = 0; i < TS_GATE_PER_ADDR + 2; i++) close_conn(&c[i]);
  close_conn(&other);
}

static void all_addresses_past_the_total_lose_the_oldest_of_all(void **state) {
  (void)state;
  ts_gate g;
  ts_gate_init(&g, "test port", NULL);
  static conn c[TS_GATE_TOTAL + 1];
  for (int i = 0; i <= TS_GATE_TOTAL; i++) {
    c[i] = open_conn();
    struct sockaddr_storage a = v4(0x0A000000u + (uint32_t)i); /* one start per address */
    ts_gate_enter(&g, c[i].ours, (struct sockaddr *)&a);
  }
  assert_true(evicted(&c[0]));
  for (int i = 1; i <= TS_GATE_TOTAL; i++) assert_false(evicted(&c[i]));
  for (int i = 0; i <= TS_GATE_TOTAL; i++) close_conn(&c[i]);
}

static void keys_are_ipv4_addresses_and_ipv6_prefixes(void **state) {
  (void)state;
  struct sockaddr_in6 x = {0}, y = {0}, z = {0}, m = {0};
  x.sin6_family = y.sin6_family = z.sin6_family = m.sin6_family = AF_INET6;
  inet_pton(AF_INET6, "2001:db8:1:2::1", &x.sin6_addr);
  inet_pton(AF_INET6, "2001:db8:1:2:ffff::9", &y.sin6_addr); /* same /64 */
  inet_pton(AF_INET6, "2001:db8:1:3::1", &z.sin6_addr);
  inet_pton(AF_INET6, "::ffff:10.0.0.1", &m.sin6_addr);
  uint8_t kx[16], ky[16], kz[16], km[16], k4[16];
  ts_gate_key((struct sockaddr *)&x, kx);
  ts_gate_key((struct sockaddr *)&y, ky);
  ts_gate_key((struct sockaddr *)&z, kz);
  ts_gate_key((struct sockaddr *)&m, km);
  struct sockaddr_storage a = v4(0x0A000001);
  ts_gate_key((struct sockaddr *)&a, k4);
  assert_memory_equal(kx, ky, 16);
  assert_memory_not_equal(kx, kz, 16);
  assert_memory_equal(km, k4, 16); /* a dual-stack listener's IPv4 peer */
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(one_address_past_its_limit_loses_its_oldest),
    cmocka_unit_test(all_addresses_past_the_total_lose_the_oldest_of_all),
    cmocka_unit_test(keys_are_ipv4_addresses_and_ipv6_prefixes),
};

TS_TEST_MAIN(tests)
