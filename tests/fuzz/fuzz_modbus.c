/* fuzz_modbus.c - libFuzzer target for the Modbus TCP request path of the
 * daemons (proto/mbplane.c): the input is what a client sends, any number
 * of requests back to back. It goes into one end of a socketpair whose
 * other end a ts_mbserver serves request by request, as a daemon's plane
 * thread does, until the server drops the connection or the input runs
 * out. Each input meets two daemons: the coordinator's map (input
 * registers 0..TS_MB_IR_SERVER_END-1, the pause coil) with
 * --modbus-control, and the worker's (0..TS_MB_IR_WORKER_END-1, the drain
 * coil) without.
 *
 * Checked, besides crashes and sanitizer reports: every request answered
 * gets exactly one reply, with its transaction and unit ids, protocol 0 and
 * a length that counts its bytes; a valid request gets the normal reply
 * (reads: the values the daemon's refresh put in the map at that moment)
 * and an invalid one the exception the Modbus spec gives it (01 function,
 * 02 address, 03 value or count); a coil write reaches the daemon, with a
 * coil of its map and a value of 0 or 1, exactly when the client sees it
 * acknowledged; a dropped connection gets no reply; every log line is one
 * line. Build and run: make fuzz. */
#include <modbus/modbus.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include <sys/ioctl.h>
#include <sys/socket.h>
#include <unistd.h>

#include "error.h"
#include "mbmap.h"
#include "mbplane.h"

int LLVMFuzzerInitialize(int *argc, char ***argv);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* More than any useful run of requests; it fits a socketpair's buffer, so
 * the whole input is written before the first request is served. */
#define INPUT_MAX 16384
#define MBAP 7 /* transaction id, protocol id, length, unit id */

/* A daemon as its plane sees it: the registers of its last refresh, its
 * one coil, and the writes it was handed. */
typedef struct {
  int role, ninput, control;
  uint16_t ir[TS_MB_MAX_INPUT];
  int coil, refreshes, writes;
} daemon_state;

static daemon_state g_daemons[2];
static ts_mbserver *g_servers[2];

/* Values a client can tell apart: the map's fixed words, one word per
 * register elsewhere, and a refresh count that changes on every request. */
static void refresh(void *ctx, uint16_t *ir, uint8_t *coils) {
  daemon_state *d = ctx;
  d->refreshes++;
  for (int k = 0; k < d->ninput; k++) ir[k] = (uint16_t)(0x1000u + 0x0101u * (unsigned)k);
  ir[TS_MB_IR_MAGIC] = TS_MB_MAGIC;
  ir[TS_MB_IR_BUILD] = TS_MB_BUILD;
  ir[TS_MB_IR_ROLE] = (uint16_t)d->role;
  ts_mb_put32(ir, TS_MB_IR_UPTIME, (uint32_t)d->refreshes);
  memcpy(d->ir, ir, sizeof(uint16_t) * (size_t)d->ninput);
  coils[0] = (uint8_t)d->coil;
}

/* What the daemons' write_coil accept (server/smon.c, worker/wmon.c): their
 * one coil. The plane must never hand over another coil, another value, or
 * a write the daemon did not allow. */
static int write_coil(void *ctx, int addr, int value) {
  daemon_state *d = ctx;
  if (!d->control || addr != 0 || (value != 0 && value != 1)) abort();
  d->coil = value;
  d->writes++;
  return 0;
}

static void log_line(const char *msg) {
  if (msg[0] == '\0' || strchr(msg, '\n') != NULL || memchr(msg, '\0', TS_ERR_LEN) == NULL) abort();
}

int LLVMFuzzerInitialize(int *argc, char ***argv) {
  (void)argc;
  (void)argv;
  static const struct {
    int role, ninput, control;
  } shape[2] = {{1, TS_MB_IR_SERVER_END, 1}, {2, TS_MB_IR_WORKER_END, 0}};
  for (int i = 0; i < 2; i++) {
    daemon_state *d = &g_daemons[i];
    d->role = shape[i].role;
    d->ninput = shape[i].ninput;
    d->control = shape[i].control;
    ts_mbplane_opts o = {NULL, d->control, d->ninput, 1, refresh, write_coil, d, log_line};
    char err[TS_ERR_LEN];
    if (ts_mbserver_new(&g_servers[i], &o, err) != 0) abort();
  }
  return 0;
}

static int u16(const uint8_t *p) { return p[0] << 8 | p[1]; }

/* The exceptions a request may get, as a bit per code (1 << code); 0 when
 * it is valid and must get the normal reply. */
static unsigned expected_exceptions(const daemon_state *d, const uint8_t *req, int len) {
  int fn = req[MBAP];
  int addr = len >= MBAP + 5 ? u16(req + MBAP + 1) : 0, count = len >= MBAP + 5 ? u16(req + MBAP + 3) : 0;
  int bytes = len >= MBAP + 6 ? req[MBAP + 5] : 0;
  switch (fn) {
  case MODBUS_FC_READ_COILS:
  case MODBUS_FC_READ_DISCRETE_INPUTS:
    if (count < 1 || count > MODBUS_MAX_READ_BITS) return 1u << 3;
    return addr + count > (fn == MODBUS_FC_READ_COILS ? 1 : 0) ? 1u << 2 : 0;
  case MODBUS_FC_READ_HOLDING_REGISTERS: /* the maps have none */
    return count < 1 || count > MODBUS_MAX_READ_REGISTERS ? 1u << 3 : 1u << 2;
  case MODBUS_FC_READ_INPUT_REGISTERS:
    if (count < 1 || count > MODBUS_MAX_READ_REGISTERS) return 1u << 3;
    return addr + count > d->ninput ? 1u << 2 : 0;
  case MODBUS_FC_WRITE_SINGLE_COIL: {
    if (!d->control) return 1u << 1;
    unsigned e = (count != 0 && count != 0xFF00 ? 1u << 3 : 0) | (addr >= 1 ? 1u << 2 : 0);
    return e;
  }
  case MODBUS_FC_WRITE_MULTIPLE_COILS:
    if (!d->control) return 1u << 1;
    if (count < 1 || count > MODBUS_MAX_WRITE_BITS || bytes != (count + 7) / 8) return 1u << 3;
    return addr + count > 1 ? 1u << 2 : 0;
  case MODBUS_FC_WRITE_SINGLE_REGISTER:
  case MODBUS_FC_MASK_WRITE_REGISTER:
    return 1u << 2;
  case MODBUS_FC_WRITE_MULTIPLE_REGISTERS:
    return count < 1 || count > MODBUS_MAX_WRITE_REGISTERS || bytes != 2 * count ? 1u << 3 : 1u << 2;
  case MODBUS_FC_WRITE_AND_READ_REGISTERS: {
    int wcount = len >= MBAP + 9 ? u16(req + MBAP + 7) : 0, wbytes = len >= MBAP + 10 ? req[MBAP + 9] : 0;
    int bad = count < 1 || count > MODBUS_MAX_WR_READ_REGISTERS || wcount < 1 ||
              wcount > MODBUS_MAX_WR_WRITE_REGISTERS || wbytes != 2 * wcount;
    return bad ? 1u << 3 : 1u << 2;
  }
  case MODBUS_FC_REPORT_SLAVE_ID:
    return 0;
  default:
    return 1u << 1;
  }
}

/* A normal reply: its length, and the values of the daemon's map. */
static void check_normal(const daemon_state *d, const uint8_t *req, int len, const uint8_t *rsp, size_t n,
                         int coil_before) {
  int fn = req[MBAP];
  int addr = len >= MBAP + 5 ? u16(req + MBAP + 1) : 0, count = len >= MBAP + 5 ? u16(req + MBAP + 3) : 0;
  switch (fn) {
  case MODBUS_FC_READ_COILS: /* the one coil, the other bits 0 */
    if (n != (size_t)(MBAP + 2 + (count + 7) / 8) || rsp[MBAP + 1] != (count + 7) / 8 ||
        rsp[MBAP + 2] != (uint8_t)d->coil)
      abort();
    break;
  case MODBUS_FC_READ_INPUT_REGISTERS:
    if (n != (size_t)(MBAP + 2 + 2 * count) || rsp[MBAP + 1] != 2 * count) abort();
    for (int k = 0; k < count; k++)
      if (u16(rsp + MBAP + 2 + 2 * k) != d->ir[addr + k]) abort();
    break;
  case MODBUS_FC_WRITE_SINGLE_COIL: /* an echo, and the daemon has it */
    if (n != (size_t)len || memcmp(rsp, req, n) != 0 || d->coil != (count != 0) || d->writes != 1) abort();
    break;
  case MODBUS_FC_WRITE_MULTIPLE_COILS:
    if (n != MBAP + 5 || memcmp(rsp + MBAP + 1, req + MBAP + 1, 4) != 0 || d->writes != 1 ||
        d->coil != (req[MBAP + 6] & 1))
      abort();
    break;
  case MODBUS_FC_REPORT_SLAVE_ID:
    if (n < MBAP + 2 || (size_t)rsp[MBAP + 1] != n - MBAP - 2 || d->coil != coil_before) abort();
    break;
  default:
    abort(); /* no other function has a normal reply in these maps */
  }
}

/* One answered request (len bytes at req) and what came back (n bytes). */
static void check_answer(daemon_state *d, const uint8_t *req, int len, const uint8_t *rsp, size_t n,
                         int coil_before) {
  if (len < MBAP + 1 || req[2] != 0 || req[3] != 0 || u16(req + 4) != len - 6) abort(); /* bad MBAP served */
  if (n < MBAP + 2 || rsp[0] != req[0] || rsp[1] != req[1] || rsp[2] != 0 || rsp[3] != 0 ||
      (size_t)u16(rsp + 4) != n - 6 || rsp[6] != req[6])
    abort();
  unsigned allowed = expected_exceptions(d, req, len);
  if (rsp[MBAP] == (uint8_t)(req[MBAP] + 0x80)) {
    /* An exception: one that fits, and nothing written. */
    if (n != MBAP + 2 || rsp[MBAP + 1] > 8 || !(allowed >> rsp[MBAP + 1] & 1) || d->writes != 0 ||
        d->coil != coil_before)
      abort();
    return;
  }
  if (rsp[MBAP] != req[MBAP] || allowed != 0) abort();
  check_normal(d, req, len, rsp, n, coil_before);
}

static int queued(int fd) {
  int n = 0;
  if (ioctl(fd, FIONREAD, &n) != 0) abort();
  return n;
}

/* Serves the input's requests on one daemon until the connection goes. */
static void serve_input(int which, const uint8_t *data, size_t size) {
  daemon_state *d = &g_daemons[which];
  int sv[2];
  if (socketpair(AF_UNIX, SOCK_STREAM | SOCK_CLOEXEC, 0, sv) != 0) abort();
  if (size > 0 && write(sv[0], data, size) != (ssize_t)size) abort();
  shutdown(sv[0], SHUT_WR); /* the client has said everything: EOF after it */
  d->coil = 0;
  size_t pos = 0;
  for (;;) {
    int before = queued(sv[1]), coil_before = d->coil;
    d->writes = 0;
    int len = ts_mbserver_serve(g_servers[which], sv[1], "fuzz-client");
    int after = queued(sv[1]);
    uint8_t rsp[MODBUS_TCP_MAX_ADU_LENGTH + 1];
    ssize_t n = recv(sv[0], rsp, sizeof(rsp), MSG_DONTWAIT);
    if (len <= 0) {
      if (n > 0 || d->writes != 0) abort(); /* dropped or ignored, yet answered */
      if (len < 0 || before == after) break;
      pos += (size_t)(before - after);
      continue;
    }
    if (n <= 0 || pos + (size_t)len > size) abort(); /* served, but no reply */
    check_answer(d, data + pos, len, rsp, (size_t)n, coil_before);
    pos += (size_t)(before - after); /* the request, and what a flush dropped */
  }
  close(sv[0]);
  close(sv[1]);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  if (size > INPUT_MAX) size = INPUT_MAX;
  for (int i = 0; i < 2; i++) serve_input(i, data, size);
  return 0;
}
