/* net.c - see net.h. */
#include "net.h"

#include <arpa/inet.h>
#include <errno.h>
#include <fcntl.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#include "error.h"
#include "util.h"

int ts_net_split(const char *addr, char *host, size_t hostcap, int *port, char *err) {
  const char *colon = strrchr(addr, ':');
  if (colon == NULL) return ts_error(err, TS_EINVAL, "address '%s': expected HOST:PORT", addr);
  const char *h = addr;
  size_t hl = (size_t)(colon - addr);
  if (hl >= 2 && h[0] == '[' && h[hl - 1] == ']') {
    h++;
    hl -= 2;
  }
  if (hl >= hostcap) return ts_error(err, TS_EINVAL, "address '%s': host name too long", addr);
  memcpy(host, h, hl);
  host[hl] = '\0';
  if (ts_parse_int(colon + 1, 0, 65535, port) != 0)
    return ts_error(err, TS_EINVAL, "address '%s': port must be 0..65535", addr);
  return 0;
}

static int resolve(const char *addr, int passive, struct addrinfo **res, char *err) {
  char host[TS_NET_ADDR_LEN], port[16];
  int p;
  int rc = ts_net_split(addr, host, sizeof(host), &p, err);
  if (rc != 0) return rc;
  snprintf(port, sizeof(port), "%d", p);
  struct addrinfo hints = {0};
  hints.ai_family = AF_UNSPEC;
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = passive ? AI_PASSIVE : 0;
  int g = getaddrinfo(host[0] ? host : NULL, port, &hints, res);
  if (g != 0) return ts_error(err, TS_ECONN, "address '%s': %s", addr, gai_strerror(g));
  return 0;
}

void ts_net_tune(int fd) {
  int one = 1;
  setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
  setsockopt(fd, SOL_SOCKET, SO_KEEPALIVE, &one, sizeof(one));
}

int ts_net_listen(const char *addr, int *fd_out, int *port_out, char *err) {
  struct addrinfo *res;
  int rc = resolve(addr, 1, &res, err);
  if (rc != 0) return rc;
  int fd = -1, saved = 0;
  for (struct addrinfo *ai = res; ai != NULL; ai = ai->ai_next) {
    fd = socket(ai->ai_family, ai->ai_socktype | SOCK_CLOEXEC, ai->ai_protocol);
    if (fd < 0) continue;
    int one = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
    if (bind(fd, ai->ai_addr, ai->ai_addrlen) == 0 && listen(fd, 128) == 0) break;
    saved = errno;
    close(fd);
    fd = -1;
  }
  freeaddrinfo(res);
  if (fd < 0) return ts_error(err, TS_ECONN, "cannot listen on %s: %s", addr, strerror(saved ? saved : EINVAL));
  if (port_out != NULL) {
    struct sockaddr_storage ss;
    socklen_t sl = sizeof(ss);
    getsockname(fd, (struct sockaddr *)&ss, &sl);
    *port_out = ntohs(ss.ss_family == AF_INET6 ? ((struct sockaddr_in6 *)&ss)->sin6_port
                                               : ((struct sockaddr_in *)&ss)->sin_port);
  }
  *fd_out = fd;
  return 0;
}

static int connect_one(const struct addrinfo *ai, int timeout_ms) {
  int fd = socket(ai->ai_family, ai->ai_socktype | SOCK_CLOEXEC | SOCK_NONBLOCK, ai->ai_protocol);
  if (fd < 0) return -1;
  if (connect(fd, ai->ai_addr, ai->ai_addrlen) != 0) {
    if (errno != EINPROGRESS) goto fail;
    struct pollfd p = {fd, POLLOUT, 0};
    if (poll(&p, 1, timeout_ms) != 1) {
      errno = ETIMEDOUT;
      goto fail;
    }
    int soerr = 0;
    socklen_t sl = sizeof(soerr);
    getsockopt(fd, SOL_SOCKET, SO_ERROR, &soerr, &sl);
    if (soerr != 0) {
      errno = soerr;
      goto fail;
    }
  }
  fcntl(fd, F_SETFL, fcntl(fd, F_GETFL) & ~O_NONBLOCK);
  ts_net_tune(fd);
  return fd;
fail:;
  int e = errno;
  close(fd);
  errno = e;
  return -1;
}

int ts_net_connect(const char *addr, int timeout_ms, int *fd_out, char *err) {
  struct addrinfo *res;
  int rc = resolve(addr, 0, &res, err);
  if (rc != 0) return rc;
  int fd = -1, saved = 0;
  for (struct addrinfo *ai = res; ai != NULL && fd < 0; ai = ai->ai_next) {
    fd = connect_one(ai, timeout_ms);
    if (fd < 0) saved = errno;
  }
  freeaddrinfo(res);
  if (fd < 0) return ts_error(err, TS_ECONN, "cannot connect to %s: %s", addr, strerror(saved));
  *fd_out = fd;
  return 0;
}

int ts_net_accept(int lfd, int *fd_out, char *peer, size_t peercap, struct sockaddr_storage *addr) {
  struct sockaddr_storage ss;
  socklen_t sl = sizeof(ss);
  int fd = accept4(lfd, (struct sockaddr *)&ss, &sl, SOCK_CLOEXEC);
  if (fd < 0) return errno == EINTR || errno == ECONNABORTED ? TS_ETIMEDOUT : TS_ECONN;
  char host[INET6_ADDRSTRLEN] = "?";
  int port = 0;
  if (ss.ss_family == AF_INET) {
    inet_ntop(AF_INET, &((struct sockaddr_in *)&ss)->sin_addr, host, sizeof(host));
    port = ntohs(((struct sockaddr_in *)&ss)->sin_port);
  } else if (ss.ss_family == AF_INET6) {
    inet_ntop(AF_INET6, &((struct sockaddr_in6 *)&ss)->sin6_addr, host, sizeof(host));
    port = ntohs(((struct sockaddr_in6 *)&ss)->sin6_port);
  }
  snprintf(peer, peercap, "%s:%d", host, port);
  if (addr != NULL) *addr = ss;
  ts_net_tune(fd);
  *fd_out = fd;
  return 0;
}

static int send_all(int fd, const uint8_t *p, size_t n) {
  while (n > 0) {
    ssize_t k = send(fd, p, n, MSG_NOSIGNAL);
    if (k < 0) {
      if (errno == EINTR) continue;
      if (errno == EAGAIN) {
        struct pollfd pf = {fd, POLLOUT, 0};
        poll(&pf, 1, 1000);
        continue;
      }
      return -1;
    }
    p += k;
    n -= (size_t)k;
  }
  return 0;
}

int ts_net_send(int fd, uint8_t type, uint32_t id, const void *payload, size_t len, char *err) {
  if (len > UINT32_MAX) return ts_error(err, TS_ETOOBIG, "message of %zu bytes is too large", len);
  uint8_t h[TS_FRAME_HEADER];
  ts_frame_header(h, type, id, (uint32_t)len);
  /* Small frames go out in one segment (one send), large ones in two. */
  if (len <= 4096) {
    uint8_t buf[TS_FRAME_HEADER + 4096];
    memcpy(buf, h, sizeof(h));
    if (len > 0) memcpy(buf + sizeof(h), payload, len);
    if (send_all(fd, buf, sizeof(h) + len) != 0) goto fail;
    return 0;
  }
  if (send_all(fd, h, sizeof(h)) != 0 || send_all(fd, payload, len) != 0) goto fail;
  return 0;
fail:
  return ts_error(err, TS_ECONN, "send failed: %s", strerror(errno));
}

/* Sends n plain bytes as sealed frames. */
static int send_sealed(ts_conn *c, const uint8_t *p, size_t n, char *err) {
  while (n > 0) {
    size_t k = n < TS_SEAL_CHUNK ? n : TS_SEAL_CHUNK;
    int len = ts_seal_one(c->seal, p, k, err);
    if (len < 0) return len;
    if (send_all(c->fd, c->seal->tx_buf, (size_t)len) != 0)
      return ts_error(err, TS_ECONN, "send failed: %s", strerror(errno));
    p += k;
    n -= k;
  }
  return 0;
}

int ts_conn_send(ts_conn *c, uint8_t type, uint32_t id, const void *payload, size_t len, char *err) {
  if (c->seal == NULL) return ts_net_send(c->fd, type, id, payload, len, err);
  if (len > UINT32_MAX) return ts_error(err, TS_ETOOBIG, "message of %zu bytes is too large", len);
  /* The header and the start of the payload in one sealed frame (a small
   * message in one), the rest straight from the payload. */
  uint8_t first[4096];
  size_t head = len < sizeof(first) - TS_FRAME_HEADER ? len : sizeof(first) - TS_FRAME_HEADER;
  ts_frame_header(first, type, id, (uint32_t)len);
  if (head > 0) memcpy(first + TS_FRAME_HEADER, payload, head);
  int rc = send_sealed(c, first, TS_FRAME_HEADER + head, err);
  if (rc == 0 && len > head) rc = send_sealed(c, (const uint8_t *)payload + head, len - head, err);
  return rc;
}

int ts_conn_wrap(ts_conn *c, ts_wr *out, const void *plain, size_t n, char *err) {
  if (c->seal != NULL) return ts_seal_append(c->seal, out, plain, n, err);
  ts_wr_bytes(out, plain, n);
  return ts_wr_status(out) != 0 ? ts_error(err, TS_ENOMEM, "out of memory for an outgoing message") : 0;
}

/* Opens the whole sealed frames received into the frame reader. */
static int open_sealed(ts_conn *c, char *err) {
  for (;;) {
    ts_frame f;
    const uint8_t *plain;
    size_t n;
    int rc = ts_frame_reader_next(&c->seal->in, &f, err);
    if (rc == 1) rc = ts_seal_open(c->seal, &f, &plain, &n, err);
    if (rc == 0) return 0;
    if (rc < 0) {
      char why[TS_ERR_LEN];
      snprintf(why, sizeof(why), "%s", err);
      return ts_error(err, rc, "%s: %s%s", c->peer, strncmp(why, "sealed link", 11) == 0 ? "" : "sealed link: ",
                      why);
    }
    if (ts_frame_reader_feed(&c->rd, plain, n) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
  }
}

int ts_conn_start_seal(ts_conn *c, const uint8_t tx_key[TS_SEAL_KEY], const uint8_t rx_key[TS_SEAL_KEY], char *err) {
  ts_seal *s = malloc(sizeof(*s));
  if (s == NULL || ts_seal_init(s, tx_key, rx_key) != 0) {
    free(s);
    return ts_error(err, TS_ENOMEM, "out of memory for a sealed link");
  }
  /* What came after the last handshake frame is sealed already. */
  ts_frame_reader *rd = &c->rd;
  size_t from = rd->consumed;
  if (rd->len > from && ts_frame_reader_feed(&s->in, rd->buf + from, rd->len - from) != 0) {
    ts_seal_free(s);
    free(s);
    return ts_error(err, TS_ENOMEM, "out of memory for a sealed link");
  }
  rd->len = from;
  c->seal = s;
  return open_sealed(c, err);
}

void ts_conn_init(ts_conn *c, int fd, uint32_t max_payload, const char *peer) {
  c->fd = fd;
  c->seal = NULL;
  ts_frame_reader_init(&c->rd, max_payload);
  ts_pieces_init(&c->pieces, 0);
  snprintf(c->peer, sizeof(c->peer), "%s", peer ? peer : "?");
}

void ts_conn_accept_pieces(ts_conn *c, uint64_t max_message) { c->pieces.max_message = max_message; }

void ts_conn_close(ts_conn *c) {
  if (c->fd >= 0) close(c->fd);
  c->fd = -1;
  ts_frame_reader_free(&c->rd);
  ts_pieces_free(&c->pieces);
  if (c->seal != NULL) {
    ts_seal_free(c->seal);
    free(c->seal);
    c->seal = NULL;
  }
}

void ts_conn_linger(ts_conn *c, int timeout_ms) {
  shutdown(c->fd, SHUT_WR);
  double deadline = ts_now() + timeout_ms / 1000.0;
  for (;;) {
    int left = (int)((deadline - ts_now()) * 1000.0);
    struct pollfd p = {c->fd, POLLIN, 0};
    if (left <= 0 || poll(&p, 1, left) <= 0) break;
    uint8_t buf[4096];
    ssize_t k = recv(c->fd, buf, sizeof(buf), MSG_DONTWAIT);
    if (k == 0 || (k < 0 && errno != EAGAIN && errno != EINTR)) break;
  }
}

int ts_conn_next(ts_conn *c, ts_frame *f, char *err) {
  for (;;) {
    ts_frame raw;
    int rc = ts_frame_reader_next(&c->rd, &raw, err);
    if (rc == 1 && (rc = ts_pieces_next(&c->pieces, &raw, f, err)) == 0) continue; /* a piece taken in */
    if (rc < 0) {
      char why[TS_ERR_LEN];
      snprintf(why, sizeof(why), "%s", err);
      return ts_error(err, rc, "%s: %s", c->peer, why);
    }
    return rc;
  }
}

/* One recv into the reader: 1 got bytes, 0 would block, or an error. */
static int fill(ts_conn *c, int dontwait, char *err) {
  uint8_t buf[65536];
  ssize_t k = recv(c->fd, buf, sizeof(buf), dontwait ? MSG_DONTWAIT : 0);
  if (k == 0 && c->seal != NULL && c->seal->in.len > c->seal->in.consumed)
    return ts_error(err, TS_ECONN, "%s closed the connection inside sealed frame %u (truncated)", c->peer,
                    (uint32_t)c->seal->rx_seq);
  if (k == 0) return ts_error(err, TS_ECONN, "%s closed the connection", c->peer);
  if (k < 0) {
    if (errno == EAGAIN || errno == EINTR) return 0;
    return ts_error(err, TS_ECONN, "%s: %s", c->peer, strerror(errno));
  }
  if (c->seal != NULL) {
    if (ts_frame_reader_feed(&c->seal->in, buf, (size_t)k) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
    int rc = open_sealed(c, err);
    return rc < 0 ? rc : 1;
  }
  if (ts_frame_reader_feed(&c->rd, buf, (size_t)k) != 0) return ts_error(err, TS_ENOMEM, "out of memory");
  return 1;
}

int ts_conn_pump(ts_conn *c, ts_frame *f, char *err) {
  int rc = ts_conn_next(c, f, err);
  if (rc != 0) return rc;
  rc = fill(c, 1, err);
  if (rc <= 0) return rc;
  return ts_conn_next(c, f, err);
}

int ts_conn_recv(ts_conn *c, ts_frame *f, int timeout_ms, char *err) {
  double deadline = ts_now() + timeout_ms / 1000.0;
  for (;;) {
    int rc = ts_conn_next(c, f, err);
    if (rc != 0) return rc;
    int wait = -1;
    if (timeout_ms >= 0) {
      double left = deadline - ts_now();
      if (left <= 0) return ts_error(err, TS_ETIMEDOUT, "%s: no answer within %d ms", c->peer, timeout_ms);
      wait = (int)(left * 1000.0) + 1;
    }
    struct pollfd p = {c->fd, POLLIN, 0};
    int n = poll(&p, 1, wait);
    if (n < 0 && errno != EINTR) return ts_error(err, TS_ECONN, "%s: poll: %s", c->peer, strerror(errno));
    if (n <= 0) continue;
    rc = fill(c, 1, err);
    if (rc < 0) return rc;
  }
}
