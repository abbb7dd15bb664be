/* mbplane.h - a daemon's Modbus TCP monitoring and control plane.
 *
 * Every daemon can serve its state as a Modbus register map (input
 * registers: read-only values; coils: switches such as `drain`) to any
 * Modbus client - SCADA software, mbpoll, the coordinator's own poller.
 * The plane runs in its own thread with its own sockets: a slow or hostile
 * Modbus client can stall only that thread, never scanning or jobs.
 * Requests are decoded and answered by libmodbus; malformed ones get a
 * Modbus exception or a dropped connection.
 *
 * Values longer than 16 bits take 2 (u32) or 4 (u64) consecutive
 * registers, most significant word first (ts_mb_put32/64). */
#ifndef TS_MBPLANE_H
#define TS_MBPLANE_H

#include <stddef.h>
#include <stdint.h>
#include <sys/socket.h>

#define TS_MB_MAX_INPUT 256 /* input registers a map may have */
#define TS_MB_MAX_COILS 16

typedef struct ts_mbplane ts_mbplane;

/* Fills the input registers and coils with the daemon's current state;
 * called in the plane's thread before every request is answered. */
typedef void ts_mb_refresh_fn(void *ctx, uint16_t *input, uint8_t *coils);
/* A client wrote `value` to coil `addr` (only with control on). 0, or a
 * negative TS_E* code: the client then gets a Modbus exception. */
typedef int ts_mb_write_fn(void *ctx, int addr, int value);

/* Who may connect: loopback peers always, others only inside one of
 * these networks (--modbus-allow); a peer outside is closed at accept. */
#define TS_MB_ALLOW_MAX 32
typedef struct {
  int family; /* AF_INET or AF_INET6 */
  int prefix; /* bits */
  uint8_t addr[16];
} ts_mb_net;
typedef struct {
  int n;
  ts_mb_net net[TS_MB_ALLOW_MAX];
} ts_mb_allow;

/* Parses "CIDR,CIDR,..." (10.0.0.0/8, 192.168.1.7, fd00::/8; an address
 * without a prefix is one host). */
int ts_mb_allow_parse(const char *list, ts_mb_allow *a, char *err);
/* 1 if a peer at sa may connect: loopback, or in a (NULL: loopback only). */
int ts_mb_allowed(const ts_mb_allow *a, const struct sockaddr *sa);

typedef struct {
  const char *listen;   /* ADDR:PORT; port 0 picks one */
  int control;          /* accept coil writes (else: exception 01) */
  int ninput, ncoils;   /* map size */
  ts_mb_refresh_fn *refresh;
  ts_mb_write_fn *write; /* may be NULL when ncoils is 0 */
  void *ctx;
  void (*log)(const char *msg); /* refused writes, dropped clients (may be NULL) */
  const ts_mb_allow *allow;     /* NULL: loopback peers only */
} ts_mbplane_opts;

/* The request side of a plane, without its thread or sockets: a libmodbus
 * context and the register map, answering one request at a time on a
 * socket the caller owns. A plane's thread serves its clients with one;
 * the fuzz target (tests/fuzz/fuzz_modbus.c) drives one over a socketpair. */
typedef struct ts_mbserver ts_mbserver;

/* A server for o's map, callbacks and control switch (o->listen unused). */
int ts_mbserver_new(ts_mbserver **out, const ts_mbplane_opts *o, char *err);
/* Reads one request from fd and answers it; peer names the client in log
 * lines. The request must be there whole (libmodbus waits a millisecond at
 * most for the rest): the plane peeks first.
 * Returns the request's length, 0 for a request ignored, or -1 when the
 * connection should be closed (why is logged, unless the client left). */
int ts_mbserver_serve(ts_mbserver *s, int fd, const char *peer);
void ts_mbserver_free(ts_mbserver *s);

/* Listens and starts the plane's thread; *port gets the bound port. */
int ts_mbplane_start(ts_mbplane **out, const ts_mbplane_opts *o, int *port, char *err);
/* Stops the thread and closes every socket. */
void ts_mbplane_stop(ts_mbplane *m);

/* The address a --modbus argument means: PORT and :PORT are loopback,
 * *:PORT every interface (so is 0.0.0.0:PORT or [::]:PORT; whoever
 * connects there must still be on loopback or in --modbus-allow). Writes
 * HOST:PORT to out and the host alone to host (for display). */
int ts_mb_listen_addr(const char *arg, char *out, size_t cap, char *host, size_t hostcap, char *err);

/* Stores v at regs[at..] as 2 or 4 registers, most significant first. */
void ts_mb_put32(uint16_t *regs, int at, uint32_t v);
void ts_mb_put64(uint16_t *regs, int at, uint64_t v);

#endif
