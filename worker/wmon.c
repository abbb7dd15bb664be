/* wmon.c - see wmon.h. */
#include "wmon.h"

#include <dirent.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>

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
  uint32_t sources_loaded, sources_held, passes;
  uint64_t rate, vectors, batches, queries;
  double scan_rate; /* bytes/s scanned in recent batches, averaged over ~1 s of scanning */
  uint64_t ran_ns, waited_ns; /* schedstat totals at the last CPU-share sample */
  double sampled_at;
  uint16_t cpu_share;         /* per mille, or TS_MB_UNKNOWN */
  ts_mbplane *plane;
} g_mon = {.lock = PTHREAD_MUTEX_INITIALIZER};

void ts_wmon_init(int threads, int simd) {
  pthread_mutex_lock(&g_mon.lock);
  g_mon.started = ts_now();
  g_mon.cpu_share = TS_MB_UNKNOWN;
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

void ts_wmon_batch(uint32_t queries, uint64_t bytes, uint64_t nanos) {
  pthread_mutex_lock(&g_mon.lock);
  g_mon.batches++;
  g_mon.queries += queries;
  if (nanos > 0 && bytes > 0) {
    double dt = (double)nanos * 1e-9, k = 1.0 - exp(-dt);
    g_mon.scan_rate = g_mon.scan_rate == 0 ? (double)bytes / dt : g_mon.scan_rate + k * ((double)bytes / dt - g_mon.scan_rate);
  }
  pthread_mutex_unlock(&g_mon.lock);
}

void ts_wmon_error(void) {
  pthread_mutex_lock(&g_mon.lock);
  g_mon.errors++;
  pthread_mutex_unlock(&g_mon.lock);
}

void ts_wmon_source(int delta) {
  pthread_mutex_lock(&g_mon.lock);
  if (delta > 0) g_mon.sources_loaded++;
  g_mon.sources_held = (uint32_t)((int)g_mon.sources_held + delta);
  pthread_mutex_unlock(&g_mon.lock);
}

void ts_wmon_pass(void) {
  pthread_mutex_lock(&g_mon.lock);
  g_mon.passes++;
  pthread_mutex_unlock(&g_mon.lock);
}

int ts_wmon_draining(void) {
  pthread_mutex_lock(&g_mon.lock);
  int d = g_mon.draining;
  pthread_mutex_unlock(&g_mon.lock);
  return d;
}

/* Time this process's threads ran on a CPU and waited runnable for one,
 * summed over /proc/self/task/<tid>/schedstat (Linux, nanoseconds). */
static int read_schedstat(uint64_t *ran, uint64_t *waited) {
  DIR *d = opendir("/proc/self/task");
  if (d == NULL) return -1;
  *ran = *waited = 0;
  struct dirent *e;
  while ((e = readdir(d)) != NULL) {
    if (e->d_name[0] == '.') continue;
    char path[300];
    snprintf(path, sizeof(path), "/proc/self/task/%s/schedstat", e->d_name);
    FILE *f = fopen(path, "r");
    unsigned long long r, w;
    if (f != NULL && fscanf(f, "%llu %llu", &r, &w) == 2) {
      *ran += r;
      *waited += w;
    }
    if (f != NULL) fclose(f);
  }
  closedir(d);
  return 0;
}

/* The CPU share over the last half second or more (lock held): a worker
 * sharing its cores with other load waits in the run queue, and its scans
 * slow down in proportion, whatever the size of its slice. */
static void sample_cpu_share(void) {
  double now = ts_now();
  if (now - g_mon.sampled_at < 0.5) return;
  uint64_t ran, waited;
  if (read_schedstat(&ran, &waited) != 0) return;
  uint64_t dr = ran - g_mon.ran_ns, dw = waited - g_mon.waited_ns;
  /* Under 20 ms of demand says nothing: the worker was idle. */
  g_mon.cpu_share = g_mon.sampled_at > 0 && dr + dw >= 20000000 ? (uint16_t)(dr * 1000 / (dr + dw)) : TS_MB_UNKNOWN;
  g_mon.ran_ns = ran;
  g_mon.waited_ns = waited;
  g_mon.sampled_at = now;
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
  sample_cpu_share();
  ir[TS_MB_IR_CPU_SHARE] = g_mon.cpu_share;
  ts_mb_put32(ir, TS_MB_IR_UPTIME, (uint32_t)(ts_now() - g_mon.started));
  ts_mb_put32(ir, TS_MB_IR_ERRORS, g_mon.errors);
  ts_mb_put64(ir, TS_MB_IR_RATE, g_mon.rate);
  ts_mb_put64(ir, TS_MB_IR_VECTORS, g_mon.vectors);
  ts_mb_put64(ir, TS_MB_IR_BATCHES, g_mon.batches);
  ts_mb_put64(ir, TS_MB_IR_QUERIES, g_mon.queries);
  ts_mb_put64(ir, TS_MB_IR_SCAN_RATE, (uint64_t)g_mon.scan_rate);
  ts_mb_put32(ir, TS_MB_IR_SOURCES_LOADED, g_mon.sources_loaded);
  ir[TS_MB_IR_SOURCES_HELD] = (uint16_t)g_mon.sources_held;
  ts_mb_put32(ir, TS_MB_IR_PASSES, g_mon.passes);
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

int ts_wmon_start_modbus(const char *listen, int control, const ts_mb_allow *allow, void (*log)(const char *msg),
                         int *port, char *err) {
  ts_mbplane_opts o = {listen, control, TS_MB_IR_WORKER_END, 1, refresh, write_coil, NULL, log, allow};
  return ts_mbplane_start(&g_mon.plane, &o, port, err);
}

void ts_wmon_stop_modbus(void) {
  ts_mbplane_stop(g_mon.plane);
  g_mon.plane = NULL;
}
