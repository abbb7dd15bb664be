/* test_mbplane.c - the Modbus plane against a real libmodbus client:
 * registers and word order, coil writes with and without control,
 * exceptions for bad addresses and functions, and clients that send
 * garbage or stop halfway losing their connection while others are
 * served. */
#include <arpa/inet.h>
#include <errno.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include "error.h"
#include "mbplane.h"
#include "ts_test.h"

typedef struct {
  int refreshes;
  int coil[2];
  int writes, last_addr, last_value;
} fake_daemon;

static void refresh(void *ctx, uint16_t *input, uint8_t *coils) {
  fake_daemon *d = ctx;
  d->refreshes++;
  input[0] = 0x5453;
  ts_mb_put32(input, 1, 0x01020304u);
  ts_mb_put64(input, 3, 0x1122334455667788ull);
  input[7] = (uint16_t)d->refreshes;
  coils[0] = (uint8_t)d->coil[0];
  coils[1] = (uint8_t)d->coil[1];
}

static int write_coil(void *ctx, int addr, int value) {
  fake_daemon *d = ctx;
  d->writes++;
  d->last_addr = addr;
  d->last_value = value;
  d->coil[addr] = value;
  return 0;
}

static ts_mbplane *start(fake_daemon *d, int control, int *port) {
  ts_mbplane_opts o = {"127.0.0.1:0", control, 8, 2, refresh, write_coil, d, NULL};
  ts_mbplane *m;
  char err[TS_ERR_LEN];
  if (ts_mbplane_start(&m, &o, port, err) != 0) fail_msg("%s", err);
  return m;
}

static modbus_t *client(int port) {
  modbus_t *c = modbus_new_tcp("127.0.0.1", port);
  assert_non_null(c);
  modbus_set_response_timeout(c, 3, 0);
  assert_int_equal(modbus_connect(c), 0);
  return c;
}

static void client_free(modbus_t *c) {
  modbus_close(c);
  modbus_free(c);
}

static void registers_and_word_order(void **state) {
  (void)state;
  fake_daemon d = {0};
  int port;
  ts_mbplane *m = start(&d, 0, &port);
  modbus_t *c = client(port);
  uint16_t r[8];
  assert_int_equal(modbus_read_input_registers(c, 0, 8, r), 8);
  assert_int_equal(r[0], 0x5453);
  assert_int_equal(r[1], 0x0102);
  assert_int_equal(r[2], 0x0304);
  assert_int_equal(r[3], 0x1122);
  assert_int_equal(r[6], 0x7788);
  uint16_t again;
  assert_int_equal(modbus_read_input_registers(c, 7, 1, &again), 1);
  assert_true(again > r[7]); /* refreshed before every answer */
  client_free(c);
  ts_mbplane_stop(m);
}

static void coil_writes_need_control(void **state) {
  (void)state;
  fake_daemon d = {0};
  int port;
  ts_mbplane *m = start(&d, 0, &port);
  modbus_t *c = client(port);
  errno = 0;
  assert_int_equal(modbus_write_bit(c, 0, 1), -1);
  assert_int_equal(errno, EMBXILFUN);
  uint8_t bits[2];
  assert_int_equal(modbus_read_bits(c, 0, 2, bits), 2); /* reading is fine */
  assert_int_equal(d.writes, 0);
  client_free(c);
  ts_mbplane_stop(m);

  m = start(&d, 1, &port);
  c = client(port);
  assert_int_equal(modbus_write_bit(c, 1, 1), 1);
  assert_int_equal(d.writes, 1);
  assert_int_equal(d.last_addr, 1);
  assert_int_equal(d.last_value, 1);
  assert_int_equal(modbus_read_bits(c, 0, 2, bits), 2);
  assert_int_equal(bits[0], 0);
  assert_int_equal(bits[1], 1);
  const uint8_t both[2] = {1, 0};
  assert_int_equal(modbus_write_bits(c, 0, 2, both), 2); /* applied before the reply */
  assert_int_equal(d.coil[0], 1);
  assert_int_equal(d.coil[1], 0);
  assert_int_equal(modbus_write_bits(c, 1, 2, both), -1); /* past the map: nothing applied */
  assert_int_equal(errno, EMBXILADD);
  assert_int_equal(d.coil[1], 0);
  client_free(c);
  ts_mbplane_stop(m);
}

static void bad_addresses_and_functions_get_exceptions(void **state) {
  (void)state;
  fake_daemon d = {0};
  int port;
  ts_mbplane *m = start(&d, 1, &port);
  modbus_t *c = client(port);
  uint16_t r[4];
  errno = 0;
  assert_int_equal(modbus_read_input_registers(c, 6, 4, r), -1); /* past the map */
  assert_int_equal(errno, EMBXILADD);
  assert_int_equal(modbus_read_registers(c, 0, 1, r), -1); /* no holding registers */
  assert_int_equal(errno, EMBXILADD);
  assert_int_equal(modbus_write_bit(c, 5, 1), -1);
  assert_int_equal(errno, EMBXILADD);
  uint8_t raw[] = {0xff, 0x2b}; /* unit, a function code the plane does not serve */
  uint8_t rsp[MODBUS_TCP_MAX_ADU_LENGTH];
  assert_true(modbus_send_raw_request(c, raw, 2) > 0);
  assert_int_equal(modbus_receive_confirmation(c, rsp), 9); /* MBAP, 0x80|function, code */
  assert_int_equal(rsp[7], 0x80 | 0x2b);
  assert_int_equal(rsp[8], MODBUS_EXCEPTION_ILLEGAL_FUNCTION);
  assert_int_equal(modbus_read_input_registers(c, 0, 1, r), 1); /* still served */
  client_free(c);
  ts_mbplane_stop(m);
}

static int raw_connect(int port) {
  int fd = socket(AF_INET, SOCK_STREAM, 0);
  struct sockaddr_in a = {.sin_family = AF_INET, .sin_port = htons((uint16_t)port)};
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  assert_int_equal(connect(fd, (struct sockaddr *)&a, sizeof(a)), 0);
  return fd;
}

/* Closed by the plane: recv sees EOF or a reset within the timeout. */
static void assert_closed(int fd) {
  struct timeval tv = {5, 0};
  setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof(tv));
  char buf[64];
  ssize_t k;
  while ((k = recv(fd, buf, sizeof(buf), 0)) > 0) {
  }
  assert_true(k == 0 || errno == ECONNRESET);
}

static void garbage_and_half_requests_lose_the_connection(void **state) {
  (void)state;
  fake_daemon d = {0};
  int port;
  ts_mbplane *m = start(&d, 0, &port);
  int garbage = raw_connect(port);
  const char junk[] = "GET / HTTP/1.1\r\nHost: x\r\n\r\n";
  assert_true(send(garbage, junk, sizeof(junk), 0) > 0);
  assert_closed(garbage);
  close(garbage);
  int half = raw_connect(port);
  assert_true(send(half, "\x00\x01\x00", 3, 0) == 3);
  modbus_t *c = client(port); /* served while the half request waits */
  uint16_t r;
  assert_int_equal(modbus_read_input_registers(c, 0, 1, &r), 1);
  assert_int_equal(r, 0x5453);
  assert_closed(half);
  close(half);
  assert_int_equal(modbus_read_input_registers(c, 0, 1, &r), 1);
  client_free(c);
  ts_mbplane_stop(m);
}

static struct sockaddr_storage v4(const char *ip) {
  struct sockaddr_storage ss = {0};
  struct sockaddr_in *in = (struct sockaddr_in *)&ss;
  in->sin_family = AF_INET;
  assert_int_equal(inet_pton(AF_INET, ip, &in->sin_addr), 1);
  return ss;
}

static struct sockaddr_storage v6(const char *ip) {
  struct sockaddr_storage ss = {0};
  struct sockaddr_in6 *in = (struct sockaddr_in6 *)&ss;
  in->sin6_family = AF_INET6;
  assert_int_equal(inet_pton(AF_INET6, ip, &in->sin6_addr), 1);
  return ss;
}

static int allowed(const ts_mb_allow *a, struct sockaddr_storage ss) {
  return ts_mb_allowed(a, (struct sockaddr *)&ss);
}

static void allow_list_admits_loopback_and_its_networks(void **state) {
  (void)state;
  ts_mb_allow a;
  char err[TS_ERR_LEN];
  assert_true(allowed(NULL, v4("127.0.0.1")) && allowed(NULL, v4("127.9.8.7")) && allowed(NULL, v6("::1")));
  assert_true(allowed(NULL, v6("::ffff:127.0.0.1")));
  assert_false(allowed(NULL, v4("10.0.0.1")) || allowed(NULL, v6("fd00::1")));
  assert_int_equal(ts_mb_allow_parse("10.1.0.0/16,192.168.1.7,fd00::/8,172.16.0.0/12", &a, err), 0);
  assert_int_equal(a.n, 4);
  assert_true(allowed(&a, v4("10.1.255.3")) && allowed(&a, v4("192.168.1.7")) && allowed(&a, v6("fd12::9")));
  assert_true(allowed(&a, v4("172.31.0.1")) && allowed(&a, v6("::ffff:10.1.0.1")));
  assert_false(allowed(&a, v4("10.2.0.1")) || allowed(&a, v4("192.168.1.8")) || allowed(&a, v6("fe80::1")));
  assert_false(allowed(&a, v4("172.32.0.1")));
  assert_true(allowed(&a, v4("127.0.0.1")));
  const char *bad[] = {"", ",", "10.0.0.0/33", "fd00::/129", "10.0.0/8", "host.example", "10.0.0.0/x"};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    assert_int_equal(ts_mb_allow_parse(bad[i], &a, err), TS_EINVAL);
    assert_non_null(strstr(err, "--modbus-allow"));
  }
}

static void listen_address_spellings(void **state) {
  (void)state;
  char out[128], host[64], err[TS_ERR_LEN];
  const struct {
    const char *arg, *addr, *host;
  } cases[] = {{"1502", "127.0.0.1:1502", "127.0.0.1"}, {":1502", "127.0.0.1:1502", "127.0.0.1"},
               {"*:1502", ":1502", "0.0.0.0"},         {"0.0.0.0:1502", "0.0.0.0:1502", "0.0.0.0"},
               {"[::]:1502", "[::]:1502", "::"},      {"10.0.0.5:0", "10.0.0.5:0", "10.0.0.5"}};
  for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
    assert_int_equal(ts_mb_listen_addr(cases[i].arg, out, sizeof(out), host, sizeof(host), err), 0);
    assert_string_equal(out, cases[i].addr);
    assert_string_equal(host, cases[i].host);
  }
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(allow_list_admits_loopback_and_its_networks),
    cmocka_unit_test(listen_address_spellings),
    cmocka_unit_test(registers_and_word_order),
    cmocka_unit_test(coil_writes_need_control),
    cmocka_unit_test(bad_addresses_and_functions_get_exceptions),
    cmocka_unit_test(garbage_and_half_requests_lose_the_connection),
};

TS_TEST_MAIN(tests)
