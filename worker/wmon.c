/* wmon.c - see wmon.h. */
#include "wmon.h"

#include <math.h>
#include <pthread.h>

#include "error.h"
#include "frame.h"
#include "mbmap.h"
#include "mbplane.h"
#include "net.h"

static struct {
  pthread_mutex_t lock;
  double started;
  int threads, simd, draining;
  uint32_t loading, errors;
  uint64_t rate, vectors, batches, queries;
  double scan_rate; /* comparisons/s of recent batches, averaged over ~1 s of scanning */
  ts_mbplane *plane;
} g_mon = {.lock = PTHREAD_MUTEX_INITIALIZER};

void ts_wmon_init(int threads, int simd) {
  pthread_mutex_lock(&g_mon.lock);
  g_mon.started = ts_now();
  g_mon.threads = threads;
  g_mon.simd = simd;
  pthread_mutex_unlock(&g_mon.lock);
}

void ts_wmon_calibrated(uint64_t rate) {
  pthread_mutex_lock(&g_mon.lock);
  g_mon.rate = rate;
  pthread_mutex_unlock(&g_mon.lock);
}

void ts_wmon_loading(int delta) {
  pthread_mutex_lock(&g_mon.lock);
  g_mon.loading = (uint32_t)((int)g_mon.loading + delta);
  pthread_mutex_unlock(&g_mon.lock);
}

void ts_wmon_vectors(int64_t delta) {
  pthread_mutex_lock(&g_mon.lock);
  g_mon.vectors = (uint64_t)((int64_t)g_mon.vectors + delta);
  pthread_mutex_unlock(&g_mon.lock);
}

void ts_wmon_batch(uint32_t queries, uint64_t pairs, uint64_t nanos) {
  pthread_mutex_lock(&g_mon.lock);
  g_mon.batches++;
  g_mon.queries += queries;
  if (nanos > 0 && pairs > 0) {
    double dt = (double)nanos * 1e-9, k = 1.0 - exp(-dt);
    g_mon.scan_rate = g_mon.scan_rate == 0 ? (double)pairs / dt : g_mon.scan_rate + k * ((double)pairs / dt - g_mon.scan_rate);
  }
  pthread_mutex_unlock(&g_mon.lock);
}

void ts_wmon_error(void) {
  pthread_mutex_lock(&g_mon.lock);
  g_mon.errors++;
  pthread_mutex_unlock(&g_mon.lock);
}

int ts_wmon_draining(void) {
  pthread_mutex_lock(&g_mon.lock);
  int d = g_mon.draining;
  pthread_mutex_unlock(&g_mon.lock);
  return d;
}

static ts_mb_state state_locked(void) {
  if (g_mon.draining) return TS_MB_DRAINING;
  if (g_mon.loading > 0) return TS_MB_LOADING;
  return g_mon.vectors > 0 ? TS_MB_SCANNING : TS_MB_IDLE;
}

static void refresh(void *ctx, uint16_t *ir, uint8_t *coils) {
  (void)ctx;
  pthread_mutex_lock(&g_mon.lock);
  ir[TS_MB_IR_MAGIC] = TS_MB_MAGIC;
  ir[TS_MB_IR_PROTOCOL] = TS_PROTO_VERSION;
  ir[TS_MB_IR_BUILD] = TS_MB_BUILD;
  ir[TS_MB_IR_ROLE] = 2;
  ir[TS_MB_IR_STATE] = (uint16_t)state_locked();
  ir[TS_MB_IR_THREADS] = (uint16_t)g_mon.threads;
  ir[TS_MB_IR_SIMD] = (uint16_t)g_mon.simd;
  ts_mb_put32(ir, TS_MB_IR_UPTIME, (uint32_t)(ts_now() - g_mon.started));
  ts_mb_put32(ir, TS_MB_IR_ERRORS, g_mon.errors);
  ts_mb_put64(ir, TS_MB_IR_RATE, g_mon.rate);
  ts_mb_put64(ir, TS_MB_IR_VECTORS, g_mon.vectors);
  ts_mb_put64(ir, TS_MB_IR_BATCHES, g_mon.batches);
  ts_mb_put64(ir, TS_MB_IR_QUERIES, g_mon.queries);
  ts_mb_put64(ir, TS_MB_IR_SCAN_RATE, (uint64_t)g_mon.scan_rate);
  coils[TS_MB_COIL_DRAIN] = (uint8_t)g_mon.draining;
  pthread_mutex_unlock(&g_mon.lock);
}

static int write_coil(void *ctx, int addr, int value) {
  (void)ctx;
  if (addr != TS_MB_COIL_DRAIN) return TS_EINVAL;
  pthread_mutex_lock(&g_mon.lock);
  g_mon.draining = value != 0;
  pthread_mutex_unlock(&g_mon.lock);
  return 0;
}

int ts_wmon_start_modbus(const char *listen, int control, void (*log)(const char *msg), int *port, char *err) {
  ts_mbplane_opts o = {listen, control, TS_MB_IR_COMMON_END, 1, refresh, write_coil, NULL, log};
  return ts_mbplane_start(&g_mon.plane, &o, port, err);
}

void ts_wmon_stop_modbus(void) {
  ts_mbplane_stop(g_mon.plane);
  g_mon.plane = NULL;
}
