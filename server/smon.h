/* smon.h - the coordinator's Modbus plane (proto/mbmap.h): identity,
 * the pool and the job queue as input registers, and the `pause` coil
 * that holds the queue. */
#ifndef TS_SERVER_MONITOR_H
#define TS_SERVER_MONITOR_H

#include "cluster.h"
#include "jobs.h"
#include "mbplane.h"

/* Serves the map on listen (see mbplane.h); *port gets the bound port.
 * jobs and cluster must outlive ts_smon_stop. */
int ts_smon_start(const char *listen, int control, const ts_mb_allow *allow, ts_jobs *jobs, ts_cluster *cluster,
                  int threads, void (*log)(const char *msg), int *port, char *err);
void ts_smon_stop(void);

#endif
