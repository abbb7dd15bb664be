/* mbplane.c - see mbplane.h.
 *
 * One thread polls the listening socket, a stop pipe and up to
 * MB_MAX_CLIENTS client sockets, and hands each readable one to its
 * ts_mbserver. libmodbus only decodes and answers: its context is never
 * connected, each client's socket is lent to it for one request
 * (modbus_set_socket). A client that sends half a request gets
 * MB_REQUEST_SECONDS to finish it, then loses its connection, so one
 * client cannot hold the plane for the others. */
#include "mbplane.h"

#include <errno.h>
#include <modbus/modbus.h>
#include <poll.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/select.h>
#include <unistd.h>

#include "error.h"
#include "net.h"

#define MB_MAX_CLIENTS 16
#define MB_REQUEST_SECONDS 1
/* How long libmodbus waits before discarding the rest of a request whose
 * count it refuses (its response timeout, 0.5 s by default): the plane's
 * thread sleeps meanwhile, so at the default one client repeating such a
 * request would stall every other client. What is still in flight after
 * this is read as the next request, which fails and drops the client. */
#define MB_FLUSH_WAIT_US 1000

struct ts_mbserver {
  ts_mbplane_opts o;
  modbus_t *mb;
  modbus_mapping_t *map;
};

struct ts_mbplane {
  ts_mbplane_opts o;
  ts_mbserver *srv;
  int lfd;
  int wake[2]; /* a byte here stops the thread */
  pthread_t thread;
  int fd[MB_MAX_CLIENTS];
  char peer[MB_MAX_CLIENTS][TS_NET_ADDR_LEN];
  int n;
};

int ts_mb_listen_addr(const char *arg, char *out, size_t cap, char *host, size_t hostcap, char *err) {
  int n = snprintf(out, cap, "%s%s", strchr(arg, ':') ? "" : "127.0.0.1:", arg);
  if (n < 0 || (size_t)n >= cap) return ts_error(err, TS_EINVAL, "--modbus %s: address too long", arg);
  int port;
  int rc = ts_net_split(out, host, hostcap, &port, err);
  if (rc == 0 && host[0] == '\0') snprintf(host, hostcap, "0.0.0.0");
  return rc;
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
    modbus_set_indication_timeout(s->mb, MB_REQUEST_SECONDS, 0);
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

static void drop_client(ts_mbplane *m, int i) {
  close(m->fd[i]);
  m->n--;
  m->fd[i] = m->fd[m->n];
  memcpy(m->peer[i], m->peer[m->n], sizeof(m->peer[i]));
}

static void accept_client(ts_mbplane *m) {
  int fd;
  char peer[TS_NET_ADDR_LEN];
  if (ts_net_accept(m->lfd, &fd, peer, sizeof(peer), NULL) != 0) return;
  if (m->n == MB_MAX_CLIENTS) {
    mb_log(&m->o, "modbus client %s refused: %d clients already connected", peer, MB_MAX_CLIENTS);
    close(fd);
    return;
  }
  m->fd[m->n] = fd;
  snprintf(m->peer[m->n], sizeof(m->peer[m->n]), "%s", peer);
  m->n++;
}

static void *plane_thread(void *arg) {
  ts_mbplane *m = arg;
  for (;;) {
    struct pollfd pf[MB_MAX_CLIENTS + 2];
    pf[0] = (struct pollfd){m->wake[0], POLLIN, 0};
    pf[1] = (struct pollfd){m->lfd, POLLIN, 0};
    for (int i = 0; i < m->n; i++) pf[i + 2] = (struct pollfd){m->fd[i], POLLIN, 0};
    int n = m->n;
    if (poll(pf, (nfds_t)n + 2, -1) < 0 && errno != EINTR) break;
    if (pf[0].revents) break;
    /* Backwards: drop_client moves the last client into the slot. */
    for (int i = n - 1; i >= 0; i--)
      if (pf[i + 2].revents && ts_mbserver_serve(m->srv, m->fd[i], m->peer[i]) < 0) drop_client(m, i);
    if (pf[1].revents & POLLIN) accept_client(m);
  }
  return NULL;
}

static void plane_free(ts_mbplane *m) {
  for (int i = 0; i < m->n; i++) close(m->fd[i]);
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
