/* client.c - see client.h. */
#include "client.h"

#include <stdio.h>
#include <stdlib.h>
#include <unistd.h>

#include "error.h"

/* Results can be large images: the client accepts frames up to 4 GiB. */
#define CLIENT_MAX_FRAME UINT32_MAX

int ts_client_connect(ts_conn *c, const char *addr, const ts_auth *auth, char *err) {
  int fd;
  int rc = ts_net_connect(addr, 5000, &fd, err);
  if (rc != 0) return rc;
  ts_conn_init(c, fd, CLIENT_MAX_FRAME, addr);
  ts_msg_ident me = {TS_ROLE_CLIENT, TS_CAP_ALL, 0, 0, ""};
  const char *user = getenv("USER");
  char host[64] = "?";
  gethostname(host, sizeof(host) - 1);
  snprintf(me.name, sizeof(me.name), "%s@%s", user ? user : "?", host);
  ts_msg_ident peer;
  rc = ts_auth_connect(c, auth, &me, &peer, 10000, err);
  if (rc == 0 && peer.role != TS_ROLE_COORD) rc = ts_error(err, TS_EPROTO, "%s is not a texsyn-server", addr);
  if (rc != 0) ts_conn_close(c);
  return rc;
}

int ts_client_next(ts_conn *c, uint8_t type, int timeout_ms, ts_frame *f, char *err) {
  int rc = ts_conn_recv(c, f, timeout_ms, err);
  if (rc < 0) return rc;
  if (f->type == TS_MSG_ERROR) {
    ts_msg_error e;
    if (ts_msg_error_read(f, &e, err) != 0) return TS_EPROTO;
    return ts_error(err, e.code, "%s", e.text);
  }
  if (f->type != type)
    return ts_error(err, TS_EPROTO, "%s answered '%c' to a '%c' request", c->peer, f->type, type);
  return 0;
}

int ts_client_call(ts_conn *c, uint8_t type, const ts_wr *payload, int timeout_ms, ts_frame *f, char *err) {
  if (ts_wr_status(payload) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
  int rc = ts_conn_send(c, type, 1, payload->buf, payload->len, err);
  if (rc != 0) return rc;
  return ts_client_next(c, type, timeout_ms, f, err);
}
