/* http.h - the operations page (README, "Operations page"): a read-only
 * HTTP server (libmicrohttpd, its own threads) with the job queue and the
 * pool as a self-refreshing HTML page (/), the same as JSON
 * (/status.json), result thumbnails (/jobs/ID/thumb.png, and small.png
 * for the strips of video frames) and Prometheus metrics (/metrics). It reads state only through the thread-safe
 * snapshots of jobs.h and cluster.h.
 *
 * Who may look: without keys, loopback peers only (403 for others), as on
 * the other planes; with keys, every page needs a page or an admin key
 * (http_auth.h), and a page beyond loopback needs HTTPS (cert and key
 * files), so no key crosses a network in the clear.
 *
 * Slow or silent connections cost a socket each, not a thread: a small
 * pool of threads polls them all, each address may hold a few at once,
 * an idle one is closed after HTTP_TIMEOUT_S and one whose request is not
 * in after HTTP_REQUEST_S (http_deadline.h), so a fresh client is still
 * served while others trickle bytes in. */
#ifndef TS_HTTP_H
#define TS_HTTP_H

#include "auth.h"
#include "cluster.h"
#include "jobs.h"

/* Serves on listen (HOST:PORT, ts_http_listen_addr), over HTTPS when
 * cert and key (PEM files) are given; *port gets the bound port. auth,
 * jobs and cluster must outlive ts_http_stop. */
int ts_http_start(const char *listen, const ts_auth *auth, const char *cert, const char *key, ts_jobs *jobs,
                  ts_cluster *cluster, int threads, int *port, char *err);
/* Stops every HTTP thread (after it, nothing reads jobs or cluster) and
 * closes the socket. No-op when not started. */
void ts_http_stop(void);

#endif
