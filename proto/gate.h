/* gate.h - the door of a daemon's TCP port before peers have authenticated.
 *
 * Anyone who reaches a port can open connections without knowing the
 * secret. Such a peer costs a thread, a descriptor and a connection slot
 * until its handshake ends, so the gate bounds what strangers can hold:
 *
 * - at most TS_GATE_PER_ADDR handshakes pending from one address (an IPv4
 *   address, an IPv6 /64) and TS_GATE_TOTAL in all. A connection past a
 *   limit evicts the oldest pending one (from that address, else from
 *   anywhere): a flood only churns through its own connections, and a
 *   fresh peer, even one behind the same address, gets its turn - its
 *   handshake takes milliseconds, the flood's would take the deadline;
 * - one deadline, TS_GATE_HANDSHAKE_MS, for a whole handshake (auth.h
 *   counts it from the first read), so a slow sender cannot stretch it
 *   frame by frame;
 * - accept() out of descriptors (EMFILE, ENFILE) or kernel memory backs
 *   off, 10 ms doubling to 0.5 s, and evicts the oldest pending handshake
 *   instead of spinning on a backlog it cannot take;
 * - what it drops is logged at most once per TS_GATE_LOG_SECONDS, counted.
 *
 * Authenticated connections leave the gate and are not counted. */
#ifndef TS_GATE_H
#define TS_GATE_H

#include <pthread.h>
#include <stdint.h>
#include <sys/socket.h>

#define TS_GATE_PER_ADDR 16
#define TS_GATE_TOTAL 256
#define TS_GATE_HANDSHAKE_MS 2000
#define TS_GATE_LOG_SECONDS 10

typedef struct {
  int fd; /* -1: free */
  uint64_t seq;
  uint8_t key[16]; /* the address, or /64 */
} ts_gate_entry;

typedef struct {
  pthread_mutex_t lock;
  ts_gate_entry e[TS_GATE_TOTAL];
  uint64_t seq;
  int backoff_ms;           /* 0: accept() is working */
  uint64_t evicted, failed; /* since the last log line */
  double logged_at;
  const char *port_name; /* "job port", "worker port": in log lines */
  void (*log)(const char *msg);
} ts_gate;

void ts_gate_init(ts_gate *g, const char *port_name, void (*log)(const char *msg));
/* Accepts the next connection (blocking), backing off when the process or
 * system is out of descriptors: 0 and the socket, its "ip:port" and
 * address, or TS_ETIMEDOUT (interrupted: check for a stop and call again). */
int ts_gate_accept(ts_gate *g, int lfd, int *fd_out, char *peer, size_t peercap, struct sockaddr_storage *addr);
/* Counts a new connection as pending; makes room first by shutting down
 * the oldest pending one from the same address, or from anywhere (its
 * thread then sees the connection closed). */
void ts_gate_enter(ts_gate *g, int fd, const struct sockaddr *addr);
/* fd authenticated, or is about to be closed (a refused peer stays
 * counted while it lingers for its 'E'): call before fd is closed. */
void ts_gate_leave(ts_gate *g, int fd);

/* The key connections are counted under: IPv4 (also mapped into IPv6)
 * by address, IPv6 by its /64. */
void ts_gate_key(const struct sockaddr *addr, uint8_t key[16]);

#endif
