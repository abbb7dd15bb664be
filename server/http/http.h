/* http.h - the operations page (README, "Operations page"): a read-only
 * HTTP server (libmicrohttpd, its own threads) with the job queue and the
 * pool as a self-refreshing HTML page (/), the same as JSON
 * (/status.json), result thumbnails (/jobs/ID/thumb.png, and small.png
 * for the strips of video frames) and Prometheus metrics (/metrics). It reads state only through the thread-safe
 * snapshots of jobs.h and cluster.h.
 *
 * Who may look: without a secret, loopback peers only (403 for others), as
 * on the other planes; with one, every page needs it (http_auth.h). */
#ifndef TS_HTTP_H
#define TS_HTTP_H

#include "auth.h"
#include "cluster.h"
#include "jobs.h"

/* Serves on listen (HOST:PORT, ts_http_listen_addr); *port gets the bound
 * port. auth, jobs and cluster must outlive ts_http_stop. */
int ts_http_start(const char *listen, const ts_auth *auth, ts_jobs *jobs, ts_cluster *cluster, int threads,
                  int *port, char *err);
/* Stops every HTTP thread (after it, nothing reads jobs or cluster) and
 * closes the socket. No-op when not started. */
void ts_http_stop(void);

#endif
