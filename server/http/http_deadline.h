/* http_deadline.h - one deadline for a whole HTTP request (issue 29).
 *
 * libmicrohttpd's connection timeout counts silence only: a client that
 * sends a header byte every few seconds keeps its connection for ever, and
 * enough of them fill the page's connection limit. This gives every
 * request a deadline from when the connection opened (or its previous
 * response was sent): a connection whose request is not in by then is shut
 * down (shutdown(2); libmicrohttpd then closes it as it would a peer that
 * went away). A thread looks twice a second. */
#ifndef TS_HTTP_DEADLINE_H
#define TS_HTTP_DEADLINE_H

#include <microhttpd.h>

/* Starts the watching thread; every request then has `seconds`. */
int ts_http_deadline_start(double seconds, char *err);
/* Stops it (after the daemon has stopped: no connection is left). */
void ts_http_deadline_stop(void);

/* The daemon's callbacks: MHD_OPTION_NOTIFY_CONNECTION,
 * MHD_OPTION_NOTIFY_COMPLETED, and a request that came in whole. */
void ts_http_deadline_notify(void *cls, struct MHD_Connection *c, void **socket_context,
                             enum MHD_ConnectionNotificationCode toe);
void ts_http_deadline_completed(void *cls, struct MHD_Connection *c, void **con_cls,
                                enum MHD_RequestTerminationCode toe);
void ts_http_deadline_request_in(struct MHD_Connection *c);

#endif
