/* smon.c - see smon.h. */
#include "smon.h"

#include "error.h"
#include "frame.h"
#include "l1.h"
#include "mbmap.h"
#include "mbplane.h"
#include "net.h"

static struct {
  ts_jobs *jobs;
  ts_cluster *cluster;
  int threads, simd;
  double started;
  ts_mbplane *plane;
} g_mon;

static void refresh(void *ctx, uint16_t *ir, uint8_t *coils) {
  (void)ctx;
  ts_cluster_stats cs;
  ts_cluster_stats_get(g_mon.cluster, &cs);
  uint32_t counts[TS_JOB_STATE_COUNT];
  ts_jobs_counts(g_mon.jobs, counts);
  ts_job_status cur;
  int running = ts_jobs_current(g_mon.jobs, &cur) == 0;
  int paused = ts_jobs_paused(g_mon.jobs);
  ir[TS_MB_IR_MAGIC] = TS_MB_MAGIC;
  ir[TS_MB_IR_PROTOCOL] = TS_PROTO_VERSION;
  ir[TS_MB_IR_BUILD] = TS_MB_BUILD;
  ir[TS_MB_IR_ROLE] = 1;
  ir[TS_MB_IR_STATE] = (uint16_t)(counts[TS_JOB_RUNNING] > 0 ? TS_MB_SCANNING : TS_MB_IDLE);
  ir[TS_MB_IR_THREADS] = (uint16_t)g_mon.threads;
  ir[TS_MB_IR_SIMD] = (uint16_t)g_mon.simd;
  ts_mb_put32(ir, TS_MB_IR_UPTIME, (uint32_t)(ts_now() - g_mon.started));
  ts_mb_put32(ir, TS_MB_IR_ERRORS, counts[TS_JOB_FAILED]);
  ts_mb_put64(ir, TS_MB_IR_RATE, cs.rate);
  ts_mb_put64(ir, TS_MB_IR_VECTORS, 0);
  ts_mb_put64(ir, TS_MB_IR_BATCHES, cs.batches);
  ts_mb_put64(ir, TS_MB_IR_QUERIES, cs.queries);
  ir[TS_MB_IR_WORKERS] = (uint16_t)cs.ready;
  ir[TS_MB_IR_QUEUED] = (uint16_t)counts[TS_JOB_QUEUED];
  ir[TS_MB_IR_RUNNING] = (uint16_t)counts[TS_JOB_RUNNING];
  ts_mb_put32(ir, TS_MB_IR_DONE, counts[TS_JOB_DONE]);
  ts_mb_put32(ir, TS_MB_IR_FAILED, counts[TS_JOB_FAILED]);
  ts_mb_put64(ir, TS_MB_IR_JOB, running ? cur.id : 0);
  ir[TS_MB_IR_PROGRESS] = (uint16_t)(running ? cur.permille : 0);
  ir[TS_MB_IR_LEVEL] = (uint16_t)(running ? cur.level : 0);
  uint32_t eta = !running || cur.eta_ms == UINT32_MAX ? UINT32_MAX : cur.eta_ms / 1000;
  ts_mb_put32(ir, TS_MB_IR_ETA, eta);
  ir[TS_MB_IR_PAUSED] = (uint16_t)paused;
  coils[TS_MB_COIL_PAUSE] = (uint8_t)paused;
}

static int write_coil(void *ctx, int addr, int value) {
  (void)ctx;
  if (addr != TS_MB_COIL_PAUSE) return TS_EINVAL;
  ts_jobs_pause(g_mon.jobs, value);
  return 0;
}

int ts_smon_start(const char *listen, int control, const ts_mb_allow *allow, ts_jobs *jobs, ts_cluster *cluster,
                  int threads, void (*log)(const char *msg), int *port, char *err) {
  const ts_l1_impl *simd;
  int rc = ts_l1_select(&simd, err);
  if (rc != 0) return rc;
  g_mon.jobs = jobs;
  g_mon.cluster = cluster;
  g_mon.threads = threads;
  g_mon.simd = simd->id;
  g_mon.started = ts_now();
  ts_mbplane_opts o = {listen, control, TS_MB_IR_SERVER_END, 1, refresh, write_coil, NULL, log, allow};
  return ts_mbplane_start(&g_mon.plane, &o, port, err);
}

void ts_smon_stop(void) {
  ts_mbplane_stop(g_mon.plane);
  g_mon.plane = NULL;
}
