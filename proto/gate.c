/* gate.c - see gate.h. */
#include "gate.h"

#include <errno.h>
#include <netinet/in.h>
#include <stdio.h>
#include <string.h>
#include <time.h>

#include "error.h"
#include "net.h"
#include "util.h"

#define BACKOFF_FIRST_MS 10
#define BACKOFF_MAX_MS 500

void ts_gate_init(ts_gate *g, const char *port_name, void (*log)(const char *msg)) {
  memset(g, 0, sizeof(*g));
  pthread_mutex_init(&g->lock, NULL);
  for (int i = 0; i < TS_GATE_TOTAL; i++) g->e[i].fd = -1;
  g->port_name = port_name;
  g->log = log;
}

void ts_gate_key(const struct sockaddr *addr, uint8_t key[16]) {
  memset(key, 0, 16);
  if (addr->sa_family == AF_INET) {
    memcpy(key, &((const struct sockaddr_in *)addr)->sin_addr, 4);
  } else if (addr->sa_family == AF_INET6) {
    const struct in6_addr *a6 = &((const struct sockaddr_in6 *)addr)->sin6_addr;
    if (IN6_IS_ADDR_V4MAPPED(a6)) memcpy(key, a6->s6_addr + 12, 4);
    else {
      key[4] = 6; /* never equal to an IPv4 key */
      memcpy(key + 8, a6->s6_addr, 8);
    }
  }
}

/* One line for what was dropped since the last (lock held). */
static void note(ts_gate *g) {
  double now = ts_now();
  if (g->log == NULL || (g->evicted == 0 && g->failed == 0) || now - g->logged_at < TS_GATE_LOG_SECONDS) return;
  char msg[TS_ERR_LEN];
  if (g->failed > 0)
    snprintf(msg, sizeof(msg),
             "%s: accept failed %llu times for want of descriptors or memory (backing off; raise the "
             "open-files limit, e.g. LimitNOFILE=, if this is not a flood); %llu pending handshakes closed",
             g->port_name, (unsigned long long)g->failed, (unsigned long long)g->evicted);
  else
    snprintf(msg, sizeof(msg),
             "%s: %llu pending handshakes closed to make room (at most %d from one address, %d in all, each "
             "given %d ms)",
             g->port_name, (unsigned long long)g->evicted, TS_GATE_PER_ADDR, TS_GATE_TOTAL, TS_GATE_HANDSHAKE_MS);
  g->log(msg);
  g->evicted = g->failed = 0;
  g->logged_at = now;
}

/* Shuts down the oldest pending connection with this key (NULL: any),
 * if there is one (lock held). Its thread closes it. */
static void evict_oldest(ts_gate *g, const uint8_t *key) {
  int oldest = -1;
  for (int i = 0; i < TS_GATE_TOTAL; i++)
    if (g->e[i].fd >= 0 && (key == NULL || memcmp(g->e[i].key, key, 16) == 0) &&
        (oldest < 0 || g->e[i].seq < g->e[oldest].seq))
      oldest = i;
  if (oldest < 0) return;
  shutdown(g->e[oldest].fd, SHUT_RDWR);
  g->e[oldest].fd = -1;
  g->evicted++;
}

static int out_of_resources(int e) { return e == EMFILE || e == ENFILE || e == ENOBUFS || e == ENOMEM; }

static void sleep_ms(int ms) {
  struct timespec ts = {ms / 1000, (long)(ms % 1000) * 1000000L};
  nanosleep(&ts, NULL);
}

int ts_gate_accept(ts_gate *g, int lfd, int *fd_out, char *peer, size_t peercap, struct sockaddr_storage *addr) {
  int rc = ts_net_accept(lfd, fd_out, peer, peercap, addr);
  int e = errno;
  pthread_mutex_lock(&g->lock);
  int wait = 0;
  if (rc == 0) {
    g->backoff_ms = 0;
  } else if (out_of_resources(e)) {
    /* Each retry would fail the same way at once: the backlog's head
     * stays there until a descriptor is free. */
    g->failed++;
    evict_oldest(g, NULL);
    g->backoff_ms = g->backoff_ms == 0 ? BACKOFF_FIRST_MS
                    : g->backoff_ms * 2 > BACKOFF_MAX_MS ? BACKOFF_MAX_MS
                                                          : g->backoff_ms * 2;
    wait = g->backoff_ms;
  }
  note(g);
  pthread_mutex_unlock(&g->lock);
  if (wait > 0) sleep_ms(wait);
  return rc == 0 ? 0 : TS_ETIMEDOUT;
}

void ts_gate_enter(ts_gate *g, int fd, const struct sockaddr *addr) {
  uint8_t key[16];
  ts_gate_key(addr, key);
  pthread_mutex_lock(&g->lock);
  int same = 0, free_slot = -1;
  for (int i = 0; i < TS_GATE_TOTAL; i++) {
    if (g->e[i].fd >= 0 && memcmp(g->e[i].key, key, 16) == 0) same++;
    if (g->e[i].fd < 0 && free_slot < 0) free_slot = i;
  }
  if (same >= TS_GATE_PER_ADDR) evict_oldest(g, key);
  else if (free_slot < 0) evict_oldest(g, NULL);
  if (free_slot < 0)
    for (int i = 0; i < TS_GATE_TOTAL && free_slot < 0; i++)
      if (g->e[i].fd < 0) free_slot = i;
  g->e[free_slot].fd = fd;
  g->e[free_slot].seq = ++g->seq;
  memcpy(g->e[free_slot].key, key, 16);
  note(g);
  pthread_mutex_unlock(&g->lock);
}

void ts_gate_leave(ts_gate *g, int fd) {
  pthread_mutex_lock(&g->lock);
  for (int i = 0; i < TS_GATE_TOTAL; i++)
    if (g->e[i].fd == fd) g->e[i].fd = -1;
  pthread_mutex_unlock(&g->lock);
}
