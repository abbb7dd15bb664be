/* net.h - TCP plumbing shared by the daemons and the client: address
 * parsing, listening and connecting sockets (TCP_NODELAY: batches are
 * latency-bound round trips), whole-frame sends and a connection that reads
 * frames with a deadline. Every failure returns a negative TS_E* code and a
 * message naming the address. */
#ifndef TS_NET_H
#define TS_NET_H

#include <stddef.h>
#include <stdint.h>

#include <sys/socket.h>

#include "frame.h"
#include "pieces.h"
#include "seal.h"
#include "util.h"

#define TS_NET_ADDR_LEN 128

/* "HOST:PORT" (HOST may be empty for all interfaces, or [v6]); port 0..65535. */
int ts_net_split(const char *addr, char *host, size_t hostcap, int *port, char *err);
/* Listens on addr; *port_out (if not NULL) gets the bound port (for port 0). */
int ts_net_listen(const char *addr, int *fd_out, int *port_out, char *err);
/* Connects to addr within timeout_ms. */
int ts_net_connect(const char *addr, int timeout_ms, int *fd_out, char *err);
/* Accepts a connection (blocking); peer gets "ip:port", addr (if not
 * NULL) the peer's address as the kernel gave it. */
int ts_net_accept(int lfd, int *fd_out, char *peer, size_t peercap, struct sockaddr_storage *addr);
/* Sets TCP_NODELAY and keepalive on a connected socket. */
void ts_net_tune(int fd);

/* Sends one frame whole (blocking; no SIGPIPE). */
int ts_net_send(int fd, uint8_t type, uint32_t id, const void *payload, size_t len, char *err);

typedef struct {
  int fd;
  ts_frame_reader rd;
  ts_pieces pieces; /* reassembles messages in pieces: refused unless enabled */
  ts_seal *seal;    /* after an authenticated handshake: every frame sealed (seal.h); NULL: plain */
  char peer[TS_NET_ADDR_LEN];
} ts_conn;

/* A connection that takes frames of at most max_payload and no pieces. */
void ts_conn_init(ts_conn *c, int fd, uint32_t max_payload, const char *peer);
/* Takes messages in pieces of up to max_message bytes from now on (0:
 * none); the frames receive hands out are then whole messages. */
void ts_conn_accept_pieces(ts_conn *c, uint64_t max_message);
/* Seals every frame from now on, both ways (seal.h), with the keys the
 * handshake derived; bytes already received past the handshake are opened
 * as sealed frames. 0 or TS_ENOMEM. */
int ts_conn_start_seal(ts_conn *c, const uint8_t tx_key[TS_SEAL_KEY], const uint8_t rx_key[TS_SEAL_KEY], char *err);
/* Sends one frame whole (blocking; no SIGPIPE), sealed if the connection is. */
int ts_conn_send(ts_conn *c, uint8_t type, uint32_t id, const void *payload, size_t len, char *err);
/* Appends n bytes of whole or partial frames to out as the socket must
 * carry them: sealed if the connection is, else as they are. For senders
 * that produce frames into a buffer as the socket drains. */
int ts_conn_wrap(ts_conn *c, ts_wr *out, const void *plain, size_t n, char *err);
/* Closes the socket and frees the reader. */
void ts_conn_close(ts_conn *c);
/* After a final 'E' to a refused peer, before closing: half-closes, then
 * discards what the peer still sends until it closes (at most
 * timeout_ms). Closing with its bytes unread would reset the connection,
 * and a reset may destroy the 'E' before the peer reads it. The caller
 * closes (gate.h: the connection is counted until then). */
void ts_conn_linger(ts_conn *c, int timeout_ms);
/* Next frame, waiting at most timeout_ms (-1 = forever): 1 and *f, or
 * TS_ETIMEDOUT, TS_ECONN (peer closed or reset), TS_EPROTO / TS_ETOOBIG
 * (bad stream: close it). *f stays valid until the next call. */
int ts_conn_recv(ts_conn *c, ts_frame *f, int timeout_ms, char *err);
/* Reads what the socket holds without blocking: 1 and a frame, 0 (nothing
 * whole yet), or an error as above. For poll()-driven loops. */
int ts_conn_pump(ts_conn *c, ts_frame *f, char *err);
/* A whole frame (or message reassembled from pieces) already buffered: 1
 * and *f, 0, or an error. */
int ts_conn_next(ts_conn *c, ts_frame *f, char *err);


#endif
