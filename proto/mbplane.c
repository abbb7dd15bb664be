/* mbplane.c - see mbplane.h.
 *
 * One thread polls the listening socket, a stop pipe and up to
 * MB_MAX_CLIENTS client sockets, and hands each client's requests to its
 * ts_mbserver. libmodbus only decodes and answers: its context is never
 * connected, each client's socket is lent to it for one request
 * (modbus_set_socket), and only once the whole request has arrived (its
 * MBAP length says how long it is; the plane peeks), so libmodbus never
 * waits on a client. Sockets are non-blocking: a client that does not
 * read its replies loses its connection instead of stalling the thread.
 *
 * Before a client is served it must be let in (loopback, or inside
 * --modbus-allow) and it holds its slot only while it is busy: a request
 * started must be whole within MB_REQUEST_SECONDS, and a client silent for
 * MB_IDLE_SECONDS is closed. A new client past MB_PER_ADDR from one
 * address, or past MB_MAX_CLIENTS in all, takes the slot of the longest
 * idle one (of that address, else of any): idle or slow sockets cannot
 * lock readers out. */
#include "mbplane.h"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <modbus/modbus.h>
#include <netinet/in.h>
#include <poll.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <unistd.h>

#include "error.h"
#include "gate.h"
#include "net.h"
#include "util.h"

#define MB_MAX_CLIENTS 64
#define MB_PER_ADDR 8
#define MB_REQUEST_SECONDS 1.0
#define MB_IDLE_SECONDS 30.0
#define MB_PEEK_MS 20         /* how often a half-received request is looked at again */
#define MB_ACCEPT_PAUSE_MS 100 /* out of descriptors: the listener rests this long */
#define MB_LOG_SECONDS 10      /* refused and evicted clients: one line per this */
/* How long libmodbus waits before discarding the rest of a request whose
 * count it refuses (its response timeout, 0.5 s by default): the plane's
 * thread sleeps meanwhile, so at the default one client repeating such a
 * request would stall every other client. What is still in flight after
 * this is read as the next request, which fails and drops the client. */
#define MB_FLUSH_WAIT_US 1000
#define MB_INDICATION_WAIT_US 1000

struct ts_mbserver {
  ts_mbplane_opts o;
  modbus_t *mb;
  modbus_mapping_t *map;
};

typedef struct {
  int fd;
  char peer[TS_NET_ADDR_LEN];
  uint8_t key[16];     /* ts_gate_key: clients counted per address */
  double active_at;    /* accepted, or last request answered */
  double partial_at;   /* a request's first bytes came (0: none pending) */
} mb_client;

struct ts_mbplane {
  ts_mbplane_opts o;
  ts_mb_allow allow;
  ts_mbserver *srv;
  int lfd;
  int wake[2]; /* a byte here stops the thread */
  pthread_t thread;
  mb_client c[MB_MAX_CLIENTS];
  int n;
  double listen_rest_until; /* accept failed for want of descriptors */
  uint64_t refused, evicted; /* since the last line about them */
  double logged_at;
};

int ts_mb_listen_addr(const char *arg, char *out, size_t cap, char *host, size_t hostcap, char *err) {
  const char *colon = strrchr(arg, ':');
  const char *port = colon ? colon + 1 : arg;
  int n;
  if (colon == NULL || colon == arg) n = snprintf(out, cap, "127.0.0.1:%s", port); /* PORT, :PORT */
  else if (colon - arg == 1 && arg[0] == '*') n = snprintf(out, cap, ":%s", port); /* every interface */
  else n = snprintf(out, cap, "%s", arg);
  if (n < 0 || (size_t)n >= cap) return ts_error(err, TS_EINVAL, "--modbus %s: address too long", arg);
  int p;
  int rc = ts_net_split(out, host, hostcap, &p, err);
  if (rc == 0 && host[0] == '\0') snprintf(host, hostcap, "0.0.0.0");
  return rc;
}

/* ---- who may connect ----------------------------------------------------- */

/* The address of sa as a network of the allow list would hold it: IPv4
 * mapped into IPv6 as IPv4. 0, or -1 for another family. */
static int net_of(const struct sockaddr *sa, int *family, uint8_t addr[16]) {
  memset(addr, 0, 16);
  if (sa->sa_family == AF_INET) {
    *family = AF_INET;
    memcpy(addr, &((const struct sockaddr_in *)sa)->sin_addr, 4);
    return 0;
  }
  if (sa->sa_family != AF_INET6) return -1;
  const struct in6_addr *a6 = &((const struct sockaddr_in6 *)sa)->sin6_addr;
  if (IN6_IS_ADDR_V4MAPPED(a6)) {
    *family = AF_INET;
    memcpy(addr, a6->s6_addr + 12, 4);
  } else {
    *family = AF_INET6;
    memcpy(addr, a6->s6_addr, 16);
  }
  return 0;
}

static int in_net(const ts_mb_net *net, int family, const uint8_t *addr) {
  if (net->family != family) return 0;
  int full = net->prefix / 8, bits = net->prefix % 8;
  if (memcmp(net->addr, addr, (size_t)full) != 0) return 0;
  if (bits == 0) return 1;
  uint8_t mask = (uint8_t)(0xFF << (8 - bits));
  return (net->addr[full] & mask) == (addr[full] & mask);
}

int ts_mb_allowed(const ts_mb_allow *a, const struct sockaddr *sa) {
  static const ts_mb_net loopback[] = {{AF_INET, 8, {127}}, {AF_INET6, 128, {[15] = 1}}};
  int family;
  uint8_t addr[16];
  if (net_of(sa, &family, addr) != 0) return 0;
  for (size_t i = 0; i < sizeof(loopback) / sizeof(loopback[0]); i++)
    if (in_net(&loopback[i], family, addr)) return 1;
  for (int i = 0; a != NULL && i < a->n; i++)
    if (in_net(&a->net[i], family, addr)) return 1;
  return 0;
}

static int parse_net(const char *s, ts_mb_net *net, char *err) {
  char buf[64];
  if (snprintf(buf, sizeof(buf), "%s", s) >= (int)sizeof(buf))
    return ts_error(err, TS_EINVAL, "--modbus-allow: '%s' is not an address or CIDR", s);
  char *slash = strchr(buf, '/');
  if (slash != NULL) *slash = '\0';
  memset(net, 0, sizeof(*net));
  if (inet_pton(AF_INET, buf, net->addr) == 1) net->family = AF_INET;
  else if (inet_pton(AF_INET6, buf, net->addr) == 1) net->family = AF_INET6;
  else
    return ts_error(err, TS_EINVAL, "--modbus-allow: '%s' is not an address or CIDR (e.g. 10.1.0.0/16, fd00::/8)",
                    s);
  int max = net->family == AF_INET ? 32 : 128;
  net->prefix = max;
  if (slash != NULL && ts_parse_int(slash + 1, 0, max, &net->prefix) != 0)
    return ts_error(err, TS_EINVAL, "--modbus-allow: '%s': the prefix must be 0..%d", s, max);
  return 0;
}

int ts_mb_allow_parse(const char *list, ts_mb_allow *a, char *err) {
  char buf[2048];
  if (snprintf(buf, sizeof(buf), "%s", list) >= (int)sizeof(buf))
    return ts_error(err, TS_EINVAL, "--modbus-allow: list too long");
  a->n = 0;
  char *save = NULL;
  for (char *t = strtok_r(buf, ",", &save); t != NULL; t = strtok_r(NULL, ",", &save)) {
    if (a->n == TS_MB_ALLOW_MAX) return ts_error(err, TS_EINVAL, "--modbus-allow: at most %d networks", TS_MB_ALLOW_MAX);
    int rc = parse_net(t, &a->net[a->n], err);
    if (rc != 0) return rc;
    a->n++;
  }
  if (a->n == 0) return ts_error(err, TS_EINVAL, "--modbus-allow: give at least one address or CIDR");
  return 0;
}

void ts_mb_put32(uint16_t *regs, int at, uint32_t v) {
  regs[at] = (uint16_t)(v >> 16);
  regs[at + 1] = (uint16_t)v;
}

void ts_mb_put64(uint16_t *regs, int at, uint64_t v) {
  ts_mb_put32(regs, at, (uint32_t)(v >> 32));
  ts_mb_put32(regs, at + 2, (uint32_t)v);
}

static void mb_log(const ts_mbplane_opts *o, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static void mb_log(const ts_mbplane_opts *o, const char *fmt, ...) {
  if (o->log == NULL) return;
  char msg[TS_ERR_LEN];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(msg, sizeof(msg), fmt, ap);
  va_end(ap);
  o->log(msg);
}

/* ---- one request ------------------------------------------------------- */

static int map_ok(const ts_mbplane_opts *o) {
  return o->ninput >= 0 && o->ninput <= TS_MB_MAX_INPUT && o->ncoils >= 0 && o->ncoils <= TS_MB_MAX_COILS &&
         (o->ncoils == 0 || o->write != NULL) && o->refresh != NULL;
}

int ts_mbserver_new(ts_mbserver **out, const ts_mbplane_opts *o, char *err) {
  *out = NULL;
  if (!map_ok(o)) return ts_error(err, TS_EINVAL, "bad Modbus register map");
  ts_mbserver *s = calloc(1, sizeof(*s));
  if (s == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  s->o = *o;
  int rc = 0;
  /* The context only parses and answers; the address is never used. */
  if ((s->mb = modbus_new_tcp("127.0.0.1", MODBUS_TCP_DEFAULT_PORT)) == NULL)
    rc = ts_error(err, TS_ENOMEM, "cannot create a Modbus context: %s", modbus_strerror(errno));
  if (rc == 0 && (s->map = modbus_mapping_new(o->ncoils, 0, 0, o->ninput)) == NULL)
    rc = ts_error(err, TS_ENOMEM, "cannot allocate the Modbus register map");
  if (rc == 0) {
    /* The plane hands libmodbus a request only once its MBAP length is all
     * there: whatever more libmodbus would wait for is not coming. */
    modbus_set_indication_timeout(s->mb, 0, MB_INDICATION_WAIT_US);
    modbus_set_response_timeout(s->mb, 0, MB_FLUSH_WAIT_US);
  }
  if (rc != 0) {
    ts_mbserver_free(s);
    return rc;
  }
  *out = s;
  return 0;
}

void ts_mbserver_free(ts_mbserver *s) {
  if (s == NULL) return;
  if (s->map) modbus_mapping_free(s->map);
  if (s->mb) {
    modbus_set_socket(s->mb, -1);
    modbus_free(s->mb);
  }
  free(s);
}

static int is_coil_write(int function) {
  return function == MODBUS_FC_WRITE_SINGLE_COIL || function == MODBUS_FC_WRITE_MULTIPLE_COILS;
}

/* The MBAP header libmodbus does not check on requests: protocol id 0
 * and a length that counts the bytes after it. */
static const char *bad_header(const uint8_t *req, int len) {
  if (req[2] != 0 || req[3] != 0) return "not Modbus TCP (protocol id is not 0)";
  if (((int)req[4] << 8 | req[5]) != len - 6) return "MBAP length does not match the request";
  return NULL;
}

/* libmodbus acknowledges a multiple-coil write whose byte count is larger
 * than its coils need, which the Modbus spec refuses (exception 03): the
 * plane refuses it first, or the client would see acknowledged a write the
 * daemon never got. */
static int coil_bytes_wrong(const uint8_t *pdu) {
  return pdu[0] == MODBUS_FC_WRITE_MULTIPLE_COILS && pdu[5] != ((pdu[3] << 8 | pdu[4]) + 7) / 8;
}

/* Hands a valid coil write (pdu: function code onwards; its byte count
 * checked) to the daemon before the reply goes out, so a client that sees
 * the write acknowledged sees its effect too. An invalid one is left to
 * modbus_reply, which answers it with the right exception. */
static void apply_coil_write(ts_mbserver *s, const char *peer, const uint8_t *pdu, int len) {
  int header = modbus_get_header_length(s->mb), addr = pdu[1] << 8 | pdu[2], count, values[TS_MB_MAX_COILS];
  if (pdu[0] == MODBUS_FC_WRITE_SINGLE_COIL) {
    int v = pdu[3] << 8 | pdu[4];
    if (len != header + 5 || (v != 0xFF00 && v != 0)) return;
    count = 1;
    values[0] = v != 0;
  } else {
    count = pdu[3] << 8 | pdu[4];
    if (count < 1 || count > TS_MB_MAX_COILS || len != header + 6 + pdu[5]) return;
    for (int k = 0; k < count; k++) values[k] = pdu[6 + k / 8] >> (k % 8) & 1;
  }
  if (addr + count > s->o.ncoils) return;
  for (int k = 0; k < count; k++)
    if (s->o.write(s->o.ctx, addr + k, values[k]) != 0)
      mb_log(&s->o, "modbus client %s: coil %d could not be set to %d", peer, addr + k, values[k]);
}

/* Answers one decoded request; -1 if the connection should go. */
static int answer(ts_mbserver *s, const char *peer, const uint8_t *req, int len) {
  const char *bad = bad_header(req, len);
  if (bad != NULL) {
    mb_log(&s->o, "modbus client %s dropped: %s", peer, bad);
    return -1;
  }
  const uint8_t *pdu = req + modbus_get_header_length(s->mb);
  s->o.refresh(s->o.ctx, s->map->tab_input_registers, s->map->tab_bits);
  int refused = !is_coil_write(pdu[0]) ? 0
                : !s->o.control        ? MODBUS_EXCEPTION_ILLEGAL_FUNCTION
                : coil_bytes_wrong(pdu) ? MODBUS_EXCEPTION_ILLEGAL_DATA_VALUE
                                        : 0;
  if (refused == MODBUS_EXCEPTION_ILLEGAL_FUNCTION)
    mb_log(&s->o, "modbus client %s: coil write refused (the daemon runs without --modbus-control)", peer);
  if (refused != 0) return modbus_reply_exception(s->mb, req, (unsigned)refused) < 0 ? -1 : 0; /* EOF: dropped */
  if (is_coil_write(pdu[0])) apply_coil_write(s, peer, pdu, len);
  if (modbus_reply(s->mb, req, len, s->map) < 0) {
    mb_log(&s->o, "modbus client %s dropped: %s", peer, modbus_strerror(errno));
    return -1;
  }
  return 0;
}

int ts_mbserver_serve(ts_mbserver *s, int fd, const char *peer) {
  /* libmodbus waits with select(), which cannot take a descriptor past
   * FD_SETSIZE (the daemons may open more: LimitNOFILE in deploy/). */
  if (fd >= FD_SETSIZE) {
    mb_log(&s->o, "modbus client %s dropped: the daemon has more connections open than libmodbus can wait on "
           "(descriptor %d, limit %d); retry when it serves fewer", peer, fd, FD_SETSIZE);
    return -1;
  }
  uint8_t req[MODBUS_TCP_MAX_ADU_LENGTH];
  modbus_set_socket(s->mb, fd);
  int len = modbus_receive(s->mb, req);
  if (len == 0) return 0; /* addressed to another unit: ignored */
  if (len < 0) {
    /* A client that leaves between requests is no news. */
    if (errno != ECONNRESET && errno != 0) mb_log(&s->o, "modbus client %s dropped: %s", peer, modbus_strerror(errno));
    return -1;
  }
  return answer(s, peer, req, len) != 0 ? -1 : len;
}

/* ---- the plane's thread ------------------------------------------------ */

/* Refused and evicted clients, counted: one line per MB_LOG_SECONDS. */
static void note(ts_mbplane *m, double now) {
  if ((m->refused == 0 && m->evicted == 0) || now - m->logged_at < MB_LOG_SECONDS) return;
  mb_log(&m->o,
         "modbus plane: %llu clients refused (not on loopback nor in --modbus-allow), %llu closed to make room "
         "(at most %d from one address, %d in all; idle ones go after %.0f s)",
         (unsigned long long)m->refused, (unsigned long long)m->evicted, MB_PER_ADDR, MB_MAX_CLIENTS,
         MB_IDLE_SECONDS);
  m->refused = m->evicted = 0;
  m->logged_at = now;
}

static void drop_client(ts_mbplane *m, int i) {
  close(m->c[i].fd);
  m->c[i] = m->c[--m->n];
}

/* The client idle longest with this key (NULL: any), or -1. */
static int idlest(const ts_mbplane *m, const uint8_t *key) {
  int best = -1;
  for (int i = 0; i < m->n; i++)
    if ((key == NULL || memcmp(m->c[i].key, key, 16) == 0) && (best < 0 || m->c[i].active_at < m->c[best].active_at))
      best = i;
  return best;
}

static void accept_client(ts_mbplane *m, double now) {
  int fd;
  char peer[TS_NET_ADDR_LEN];
  struct sockaddr_storage ss;
  if (ts_net_accept(m->lfd, &fd, peer, sizeof(peer), &ss) != 0) {
    if (errno == EMFILE || errno == ENFILE || errno == ENOBUFS || errno == ENOMEM)
      m->listen_rest_until = now + MB_ACCEPT_PAUSE_MS / 1000.0;
    return;
  }
  if (!ts_mb_allowed(m->o.allow, (struct sockaddr *)&ss)) {
    m->refused++;
    close(fd);
    return;
  }
  mb_client c = {fd, "", {0}, now, 0};
  snprintf(c.peer, sizeof(c.peer), "%s", peer);
  ts_gate_key((struct sockaddr *)&ss, c.key);
  int same = 0;
  for (int i = 0; i < m->n; i++) same += memcmp(m->c[i].key, c.key, 16) == 0;
  int out = same >= MB_PER_ADDR ? idlest(m, c.key) : m->n == MB_MAX_CLIENTS ? idlest(m, NULL) : -1;
  if (out >= 0) {
    m->evicted++;
    drop_client(m, out);
  }
  fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) | O_NONBLOCK);
  m->c[m->n++] = c;
}

/* Whether the client's next request is all there: 1, 0 (not yet), -1
 * (the connection is closed, or no Modbus TCP request can be this long). */
static int request_whole(const mb_client *c) {
  uint8_t head[MODBUS_TCP_MAX_ADU_LENGTH];
  ssize_t k = recv(c->fd, head, sizeof(head), MSG_PEEK | MSG_DONTWAIT);
  if (k == 0 || (k < 0 && errno != EAGAIN && errno != EINTR)) return -1;
  if (k < 6) return 0;
  int len = head[4] << 8 | head[5];
  if (len < 2 || 6 + len > MODBUS_TCP_MAX_ADU_LENGTH) return -1;
  return k >= 6 + len;
}

/* Serves what a readable (or half-received) client sent; -1: drop it. */
static int serve_client(ts_mbplane *m, mb_client *c, double now) {
  int whole = request_whole(c);
  if (whole < 0) return -1;
  if (whole == 0) {
    if (c->partial_at == 0) c->partial_at = now;
    if (now - c->partial_at <= MB_REQUEST_SECONDS) return 0;
    mb_log(&m->o, "modbus client %s dropped: a request not whole within %.0f s", c->peer, MB_REQUEST_SECONDS);
    return -1;
  }
  c->partial_at = 0;
  c->active_at = now;
  return ts_mbserver_serve(m->srv, c->fd, c->peer) < 0 ? -1 : 0;
}

/* Poll timeout: the next half-received request to look at again, the
 * next idle client to close, or the listener's rest to end. */
static int next_wake_ms(const ts_mbplane *m, double now) {
  double next = -1;
  for (int i = 0; i < m->n; i++) {
    double t = m->c[i].partial_at > 0 ? now + MB_PEEK_MS / 1000.0 : m->c[i].active_at + MB_IDLE_SECONDS;
    if (next < 0 || t < next) next = t;
  }
  if (m->listen_rest_until > now && (next < 0 || m->listen_rest_until < next)) next = m->listen_rest_until;
  if (next < 0) return -1;
  return next <= now ? 0 : (int)((next - now) * 1000.0) + 1;
}

static void *plane_thread(void *arg) {
  ts_mbplane *m = arg;
  for (;;) {
    struct pollfd pf[MB_MAX_CLIENTS + 2];
    double now = ts_now();
    pf[0] = (struct pollfd){m->wake[0], POLLIN, 0};
    /* A resting listener, and a half-received request (looked at again
     * every MB_PEEK_MS), are left out: their data would wake us at once. */
    pf[1] = (struct pollfd){m->listen_rest_until > now ? -1 : m->lfd, POLLIN, 0};
    for (int i = 0; i < m->n; i++) pf[i + 2] = (struct pollfd){m->c[i].fd, m->c[i].partial_at > 0 ? 0 : POLLIN, 0};
    int n = m->n;
    if (poll(pf, (nfds_t)n + 2, next_wake_ms(m, now)) < 0 && errno != EINTR) break;
    if (pf[0].revents) break;
    now = ts_now();
    /* Backwards: drop_client moves the last client into the slot. */
    for (int i = n - 1; i >= 0; i--) {
      mb_client *c = &m->c[i];
      int busy = pf[i + 2].revents != 0 || c->partial_at > 0;
      if (busy && serve_client(m, c, now) < 0) drop_client(m, i);
      else if (!busy && now - c->active_at > MB_IDLE_SECONDS) drop_client(m, i);
    }
    if (pf[1].revents & POLLIN) accept_client(m, now);
    note(m, now);
  }
  return NULL;
}

static void plane_free(ts_mbplane *m) {
  for (int i = 0; i < m->n; i++) close(m->c[i].fd);
  if (m->lfd >= 0) close(m->lfd);
  for (int k = 0; k < 2; k++)
    if (m->wake[k] >= 0) close(m->wake[k]);
  ts_mbserver_free(m->srv);
  free(m);
}

int ts_mbplane_start(ts_mbplane **out, const ts_mbplane_opts *o, int *port, char *err) {
  *out = NULL;
  ts_mbplane *m = calloc(1, sizeof(*m));
  if (m == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  m->o = *o;
  if (o->allow != NULL) {
    m->allow = *o->allow; /* the caller's may go */
    m->o.allow = &m->allow;
  }
  m->lfd = m->wake[0] = m->wake[1] = -1;
  int rc = ts_mbserver_new(&m->srv, o, err);
  if (rc == 0) rc = ts_net_listen(o->listen, &m->lfd, port, err);
  if (rc == 0 && pipe(m->wake) != 0) rc = ts_error(err, TS_EIO, "pipe: %s", strerror(errno));
  if (rc == 0 && pthread_create(&m->thread, NULL, plane_thread, m) != 0)
    rc = ts_error(err, TS_ENOMEM, "cannot start the Modbus thread");
  if (rc != 0) {
    plane_free(m);
    return rc;
  }
  *out = m;
  return 0;
}

void ts_mbplane_stop(ts_mbplane *m) {
  if (m == NULL) return;
  ssize_t k = write(m->wake[1], "x", 1);
  (void)k;
  pthread_join(m->thread, NULL);
  plane_free(m);
}
