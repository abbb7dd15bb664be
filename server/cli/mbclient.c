/* mbclient.c - see mbclient.h. */
#include "mbclient.h"

#include <errno.h>
#include <getopt.h>
#include <modbus/modbus.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "l1.h"
#include "mbmap.h"
#include "net.h"
#include "suggest.h"

static const char *kUsage =
    "usage: texsyn modbus HOST:PORT [--set drain=0|1 | --set pause=0|1]\n"
    "\n"
    "Reads the Modbus register map of a texsyn-worker or texsyn-server started with\n"
    "--modbus and prints it, one `name value` per line. --set writes a coil (the daemon\n"
    "must run with --modbus-control): drain on a worker, pause on the coordinator.\n";

static uint32_t get32(const uint16_t *r, int at) { return (uint32_t)r[at] << 16 | r[at + 1]; }
static uint64_t get64(const uint16_t *r, int at) { return (uint64_t)get32(r, at) << 32 | get32(r, at + 2); }

static const char *state_name(int s) {
  static const char *const names[] = {"idle", "loading", "scanning", "draining", "failed"};
  return s >= 0 && s <= TS_MB_FAILED ? names[s] : "unknown";
}

static void print_common(const uint16_t *r) {
  const ts_l1_impl *simd = r[TS_MB_IR_SIMD] < TS_SIMD_COUNT ? ts_l1_impl_get((ts_simd)r[TS_MB_IR_SIMD]) : NULL;
  printf("magic 0x%04x\nprotocol %u\nbuild %u\nrole %s\nstate %s\nthreads %u\nsimd %s\n", r[TS_MB_IR_MAGIC],
         r[TS_MB_IR_PROTOCOL], r[TS_MB_IR_BUILD], r[TS_MB_IR_ROLE] == 1 ? "coordinator" : "worker",
         state_name(r[TS_MB_IR_STATE]), r[TS_MB_IR_THREADS], simd ? simd->name : "?");
  if (r[TS_MB_IR_CPU_SHARE] == TS_MB_UNKNOWN) printf("cpu_share unknown\n");
  else printf("cpu_share %u\n", r[TS_MB_IR_CPU_SHARE]);
  printf("uptime_s %u\nerrors %u\nrate %llu\nvectors %llu\nbatches %llu\nqueries %llu\n", get32(r, TS_MB_IR_UPTIME),
         get32(r, TS_MB_IR_ERRORS), (unsigned long long)get64(r, TS_MB_IR_RATE),
         (unsigned long long)get64(r, TS_MB_IR_VECTORS), (unsigned long long)get64(r, TS_MB_IR_BATCHES),
         (unsigned long long)get64(r, TS_MB_IR_QUERIES));
  printf("scan_rate %llu\n", (unsigned long long)get64(r, TS_MB_IR_SCAN_RATE));
}

static void print_worker(const uint16_t *r) {
  printf("sources_loaded %u\nsources_held %u\npasses %u\n", get32(r, TS_MB_IR_SOURCES_LOADED),
         r[TS_MB_IR_SOURCES_HELD], get32(r, TS_MB_IR_PASSES));
}

static void print_coordinator(const uint16_t *r) {
  uint32_t eta = get32(r, TS_MB_IR_ETA);
  printf("workers %u\nqueued %u\nrunning %u\ndone %u\nfailed %u\njob %llu\nprogress %u\nlevel %u\n",
         r[TS_MB_IR_WORKERS], r[TS_MB_IR_QUEUED], r[TS_MB_IR_RUNNING], get32(r, TS_MB_IR_DONE),
         get32(r, TS_MB_IR_FAILED), (unsigned long long)get64(r, TS_MB_IR_JOB), r[TS_MB_IR_PROGRESS],
         r[TS_MB_IR_LEVEL]);
  if (eta == UINT32_MAX) printf("eta_s unknown\n");
  else printf("eta_s %u\n", eta);
  printf("paused %u\n", r[TS_MB_IR_PAUSED]);
}

/* --set NAME=0|1: the coil and its value, checked against the role. */
static int parse_set(const char *arg, int role, int *coil, int *value, char *err) {
  const char *want = role == 1 ? "pause" : "drain";
  size_t n = strlen(want);
  if (strncmp(arg, want, n) != 0 || arg[n] != '=' || (strcmp(arg + n + 1, "0") != 0 && strcmp(arg + n + 1, "1") != 0))
    return ts_error(err, TS_EINVAL, "--set %s: a %s takes %s=0 or %s=1", arg, role == 1 ? "coordinator" : "worker",
                    want, want);
  *coil = role == 1 ? TS_MB_COIL_PAUSE : TS_MB_COIL_DRAIN;
  *value = arg[n + 1] == '1';
  return 0;
}

static int run(const char *addr, const char *set, char *err) {
  char host[TS_NET_ADDR_LEN], port_s[8];
  int port;
  int rc = ts_net_split(addr, host, sizeof(host), &port, err);
  if (rc != 0) return rc;
  snprintf(port_s, sizeof(port_s), "%d", port);
  modbus_t *m = modbus_new_tcp_pi(host[0] ? host : "127.0.0.1", port_s);
  if (m == NULL) return ts_error(err, TS_ENOMEM, "cannot create a Modbus context: %s", modbus_strerror(errno));
  modbus_set_response_timeout(m, 3, 0);
  uint16_t r[TS_MB_IR_SERVER_END];
  if (modbus_connect(m) != 0) rc = ts_error(err, TS_ECONN, "%s: %s", addr, modbus_strerror(errno));
  else if (modbus_read_input_registers(m, 0, TS_MB_IR_COMMON_END, r) != TS_MB_IR_COMMON_END)
    rc = ts_error(err, TS_EPROTO, "%s: reading registers: %s", addr, modbus_strerror(errno));
  else if (r[TS_MB_IR_MAGIC] != TS_MB_MAGIC)
    rc = ts_error(err, TS_EPROTO, "%s is a Modbus device but not a texsyn daemon", addr);
  int coordinator = rc == 0 && r[TS_MB_IR_ROLE] == 1;
  int end = coordinator ? TS_MB_IR_SERVER_END : TS_MB_IR_WORKER_END;
  if (rc == 0 && modbus_read_input_registers(m, TS_MB_IR_COMMON_END, end - TS_MB_IR_COMMON_END, r + TS_MB_IR_COMMON_END) < 0)
    rc = ts_error(err, TS_EPROTO, "%s: reading registers: %s%s", addr, modbus_strerror(errno),
                  coordinator ? "" : " (a worker older than register-map build 5?)");
  int coil = 0, value = 0;
  if (rc == 0 && set != NULL) rc = parse_set(set, coordinator ? 1 : 2, &coil, &value, err);
  if (rc == 0 && set != NULL && modbus_write_bit(m, coil, value) != 1)
    rc = ts_error(err, TS_EINVAL, "%s: writing %s: %s%s", addr, set, modbus_strerror(errno),
                  errno == EMBXILFUN ? " (start the daemon with --modbus-control and --modbus-allow)" : "");
  if (rc == 0 && set == NULL) {
    print_common(r);
    if (coordinator) print_coordinator(r);
    else print_worker(r);
  }
  modbus_close(m);
  modbus_free(m);
  return rc;
}

int ts_mbclient_main(int argc, char **argv) {
  static const struct option longopts[] = {
      {"set", required_argument, 0, 's'}, {"help", no_argument, 0, 'h'}, {0, 0, 0, 0}};
  const char *addr = NULL, *set = NULL;
  char err[TS_ERR_LEN];
  optind = 1;
  opterr = 0;
  int c;
  while ((c = getopt_long(argc, argv, "h", longopts, NULL)) != -1) {
    if (c == 'h') {
      printf("%s", kUsage);
      return 0;
    }
    if (c == 's') {
      set = optarg;
      continue;
    }
    ts_arg_unknown("modbus", argv[optind - 1], longopts, err);
    fprintf(stderr, "texsyn modbus: %s\n", err);
    return 2;
  }
  if (optind < argc) addr = argv[optind++];
  if (optind < argc) {
    fprintf(stderr, "texsyn modbus: unexpected argument '%s'\n%s", argv[optind], kUsage);
    return 2;
  }
  if (addr == NULL) {
    fprintf(stderr, "texsyn modbus: give the daemon's Modbus HOST:PORT\n%s", kUsage);
    return 2;
  }
  if (run(addr, set, err) != 0) {
    fprintf(stderr, "texsyn modbus: %s\n", err);
    return 1;
  }
  return 0;
}
