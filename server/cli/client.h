/* client.h - the client side of the job plane (texsyn synth --server,
 * status, watch, fetch, cancel, workers). */
#ifndef TS_CLIENT_H
#define TS_CLIENT_H

#include "auth.h"
#include "msg.h"
#include "net.h"

/* Connects to a coordinator, identifies as a client and, with a secret
 * (auth may be NULL), authenticates both ways. */
int ts_client_connect(ts_conn *c, const char *addr, const ts_auth *auth, char *err);
/* Sends a request and waits for its reply of the same type (timeout_ms, -1
 * forever); an 'E' reply becomes its error code and text. */
int ts_client_call(ts_conn *c, uint8_t type, const ts_wr *payload, int timeout_ms, ts_frame *reply,
                   char *err);
/* Waits for the next frame of a request already sent (watch updates). */
int ts_client_next(ts_conn *c, uint8_t type, int timeout_ms, ts_frame *reply, char *err);

#endif
