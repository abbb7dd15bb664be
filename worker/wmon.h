/* wmon.h - what a worker tells its Modbus plane (proto/mbmap.h): its
 * identity, state and counters, kept up to date by the connection threads,
 * and the `drain` coil. Every function is thread-safe. */
#ifndef TS_WORKER_MONITOR_H
#define TS_WORKER_MONITOR_H

#include <stdint.h>

#include "mbplane.h"

void ts_wmon_init(int threads, int simd);
void ts_wmon_calibrated(uint64_t rate);  /* bytes scanned per second */
void ts_wmon_loading(int delta);         /* +1 when a slice load starts, -1 when it ends */
void ts_wmon_vectors(int64_t delta);     /* vectors held */
/* A batch answered: its queries, comparisons and scan time. */
void ts_wmon_batch(uint32_t queries, uint64_t bytes, uint64_t nanos); /* bytes scanned */
void ts_wmon_error(void);                /* a failed request or a protocol error */
/* PatchMatch sources: one loaded (+1) or freed (-1); a pass answered. */
void ts_wmon_source(int delta);
void ts_wmon_pass(void);
/* 1 while the drain coil is set: the coordinator gives no new slices. */
int ts_wmon_draining(void);

/* Serves the worker's register map on listen (see mbplane.h); *port gets
 * the bound port. Coil writes need control. */
int ts_wmon_start_modbus(const char *listen, int control, const ts_mb_allow *allow, void (*log)(const char *msg),
                         int *port, char *err);
void ts_wmon_stop_modbus(void);

#endif
