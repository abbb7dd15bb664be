/* delay_relay.c - a TCP forwarder that adds a fixed one-way delay in each
 * direction: a user-space stand-in for `tc qdisc ... netem delay` where the
 * kernel lacks the netem qdisc (bench/netem.py uses it then).
 *
 * For every connection accepted on LISTEN it dials TARGET and forwards the
 * bytes both ways. Every chunk read from one side is stamped with its
 * arrival time and written to the other side DELAY microseconds later, in
 * order: TCP stream semantics are kept exactly (same bytes, same order, a
 * half-close forwarded after the bytes before it). A round trip through
 * the relay therefore gains 2 x DELAY, plus the relay's own forwarding
 * cost, which it measures: for every chunk, the time from its arrival to
 * the moment its first byte is written on, so the added delay actually
 * achieved (median, p99, max) is known, not assumed.
 *
 * Timing without busy-waiting (the machine has 2 cores, and a spinning
 * relay would steal them from the workers it serves): one thread, epoll,
 * and epoll_pwait2's nanosecond timeout set to the earliest due chunk;
 * PR_SET_TIMERSLACK 1 ns so the kernel does not round those sleeps up by
 * its default 50 us slack. TCP_NODELAY on both sockets: a delayed chunk
 * must leave at once, not wait for Nagle.
 *
 * --fifo runs the relay at real-time priority (SCHED_FIFO 1, root only): a
 * relay that sleeps between chunks then wakes on time even when the
 * workers keep both cores busy, as netem's kernel timers do. It is
 * asleep whenever nothing is due, so it takes no time from them.
 *
 * Control on stdin, one command per line (answers on stdout):
 *   delay US   one-way delay for chunks read from now on (0..10000000)
 *   stats      print the statistics as one JSON line and reset them
 * SIGTERM or SIGINT prints the statistics and exits 0.
 *
 * Usage: delay_relay --listen HOST:PORT --target HOST:PORT [--delay-us US] [--fifo]
 * First line on stdout: "delay_relay: listening on HOST:PORT ...".
 * Exit status 2 for bad options, 1 for a failure to set up. */
#include <arpa/inet.h>
#include <errno.h>
#include <getopt.h>
#include <netdb.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <sched.h>
#include <signal.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/epoll.h>
#include <sys/prctl.h>
#include <sys/signalfd.h>
#include <sys/socket.h>
#include <time.h>
#include <unistd.h>

#define READ_MAX (64 * 1024)           /* bytes per read, one chunk each */
#define QUEUE_CAP (8u * 1024 * 1024)   /* a direction stops reading above this */
#define HIST_BINS 1000000              /* achieved-delay histogram: 100 ns bins up to 100 ms */
#define HIST_NS 100
#define MAX_DELAY_US 10000000.0
#define MAX_EVENTS 64
#define GONE UINT32_MAX                /* conn.mask: the fd left the epoll set */

/* A chunk read from one side, waiting for its due time. A zero-length
 * chunk with eof set is the reader's end of stream, forwarded as a
 * half-close once the bytes before it are out. */
typedef struct chunk {
  struct chunk *next;
  uint64_t arrived, due; /* CLOCK_MONOTONIC ns */
  uint32_t len, off;
  int eof;
  unsigned char data[];
} chunk;

typedef struct {
  chunk *head, *tail;
  size_t bytes;
  int blocked; /* the destination socket is full: wait for EPOLLOUT */
  int reading; /* the source has not reached its end of stream */
  int shut;    /* the half-close was forwarded */
} queue;

struct conn;
typedef struct {
  struct conn *c; /* NULL: the listening socket, stdin or the signalfd */
  int side;       /* 0 client, 1 upstream; for c == NULL: which fd */
} endpoint;

/* One forwarded connection: q[s] holds what fd[s] sent, for fd[!s]. */
typedef struct conn {
  int fd[2];
  uint32_t mask[2]; /* epoll interest registered per fd */
  endpoint ep[2];
  queue q[2];
  int connected; /* the upstream connect() completed */
  struct conn *next;
} conn;

enum { EP_LISTEN, EP_STDIN, EP_SIGNAL };

static struct {
  int epfd, lfd;
  struct sockaddr_storage target;
  socklen_t target_len;
  uint64_t delay_ns;
  double delay_us;
  conn *conns;
  uint32_t hist[HIST_BINS];
  uint64_t chunks, bytes, max_ns;
} R;

static uint64_t now_ns(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (uint64_t)t.tv_sec * 1000000000u + (uint64_t)t.tv_nsec;
}

/* ---- statistics ------------------------------------------------------------ */

static void stats_note(uint64_t held_ns, uint32_t len) {
  uint64_t bin = held_ns / HIST_NS;
  if (bin < HIST_BINS) R.hist[bin]++; /* beyond: the quantiles fall back to the max */
  if (held_ns > R.max_ns) R.max_ns = held_ns;
  R.chunks++;
  R.bytes += len;
}

/* The held time at quantile q, in us (its bin's upper edge: never under
 * the true value, at most 0.1 us over). */
static double stats_quantile(double q) {
  uint64_t rank = (uint64_t)(q * (double)(R.chunks - 1)), seen = 0;
  for (int i = 0; i < HIST_BINS; i++) {
    seen += R.hist[i];
    if (seen > rank) return (double)(i + 1) * HIST_NS / 1000;
  }
  return (double)R.max_ns / 1000;
}

static void stats_print(void) {
  if (R.chunks == 0)
    printf("{\"delay_us\": %.1f, \"chunks\": 0, \"bytes\": 0}\n", R.delay_us);
  else
    printf("{\"delay_us\": %.1f, \"chunks\": %llu, \"bytes\": %llu, \"median_us\": %.1f, \"p99_us\": %.1f, "
           "\"max_us\": %.1f}\n",
           R.delay_us, (unsigned long long)R.chunks, (unsigned long long)R.bytes, stats_quantile(0.5),
           stats_quantile(0.99), (double)R.max_ns / 1000);
  fflush(stdout);
  memset(R.hist, 0, sizeof(R.hist));
  R.chunks = R.bytes = R.max_ns = 0;
}

/* ---- connections ----------------------------------------------------------- */

static void conn_close(conn *c) {
  for (conn **p = &R.conns; *p != NULL; p = &(*p)->next)
    if (*p == c) {
      *p = c->next;
      break;
    }
  for (int s = 0; s < 2; s++) {
    close(c->fd[s]); /* also leaves the epoll set */
    for (chunk *k = c->q[s].head, *n; k != NULL; k = n) {
      n = k->next;
      free(k);
    }
  }
  free(c);
}

/* Registers what fd[s] waits for: input while its direction reads and
 * has room, output while the queue towards it is blocked (or, upstream,
 * while the connect is in progress). */
static int conn_watch(conn *c, int s) {
  uint32_t m = 0;
  if (c->mask[s] == GONE) return 0;
  if (c->q[s].reading && c->q[s].bytes < QUEUE_CAP) m |= EPOLLIN;
  if (c->q[!s].blocked || (s == 1 && !c->connected)) m |= EPOLLOUT;
  if (m == c->mask[s]) return 0;
  struct epoll_event ev = {.events = m, .data.ptr = &c->ep[s]};
  c->mask[s] = m;
  return epoll_ctl(R.epfd, EPOLL_CTL_MOD, c->fd[s], &ev);
}

static void nodelay(int fd) {
  int one = 1;
  setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
}

static int conn_open(int cfd) {
  conn *c = calloc(1, sizeof(*c));
  int ufd = socket(R.target.ss_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0);
  if (c == NULL || ufd < 0) goto fail;
  nodelay(cfd);
  nodelay(ufd);
  if (connect(ufd, (struct sockaddr *)&R.target, R.target_len) == 0) c->connected = 1;
  else if (errno != EINPROGRESS) goto fail;
  c->fd[0] = cfd;
  c->fd[1] = ufd;
  for (int s = 0; s < 2; s++) {
    c->ep[s] = (endpoint){c, s};
    c->q[s].reading = 1;
    struct epoll_event ev = {.events = 0, .data.ptr = &c->ep[s]};
    if (epoll_ctl(R.epfd, EPOLL_CTL_ADD, c->fd[s], &ev) != 0) goto fail;
  }
  if (conn_watch(c, 0) != 0 || conn_watch(c, 1) != 0) goto fail;
  c->next = R.conns;
  R.conns = c;
  return 0;
fail:
  close(cfd); /* closing leaves the epoll set too */
  if (ufd >= 0) close(ufd);
  free(c);
  return -1;
}

static void queue_push(queue *q, chunk *k) {
  k->next = NULL;
  if (q->tail != NULL) q->tail->next = k;
  else q->head = k;
  q->tail = k;
  q->bytes += k->len;
}

static void queue_pop(queue *q) {
  chunk *k = q->head;
  q->head = k->next;
  if (q->head == NULL) q->tail = NULL;
  q->bytes -= k->len;
  free(k);
}

/* One read from fd[s] into a new chunk. Returns -1 when the connection
 * must close (a read error or no memory). */
static int conn_read(conn *c, int s) {
  static unsigned char buf[READ_MAX];
  ssize_t n = read(c->fd[s], buf, sizeof(buf));
  if (n < 0) return errno == EAGAIN || errno == EINTR ? 0 : -1;
  uint64_t t = now_ns();
  chunk *k = malloc(sizeof(*k) + (size_t)n);
  if (k == NULL) return -1;
  *k = (chunk){.arrived = t, .due = t + R.delay_ns, .len = (uint32_t)n, .eof = n == 0};
  memcpy(k->data, buf, (size_t)n);
  queue_push(&c->q[s], k);
  if (n == 0) c->q[s].reading = 0;
  return 0;
}

/* Writes the chunks of q[s] that are due to fd[!s]. Returns -1 when the
 * connection must close. */
static int conn_flush(conn *c, int s) {
  queue *q = &c->q[s];
  int dst = c->fd[!s];
  if (!c->connected || q->blocked) return 0;
  uint64_t t = now_ns();
  while (q->head != NULL && q->head->due <= t) {
    chunk *k = q->head;
    if (k->eof) {
      if (shutdown(dst, SHUT_WR) != 0) return -1;
      q->shut = 1;
      queue_pop(q);
      continue;
    }
    ssize_t n = write(dst, k->data + k->off, k->len - k->off);
    if (n < 0) {
      if (errno != EAGAIN && errno != EINTR) return -1;
      q->blocked = errno == EAGAIN;
      return 0;
    }
    if (k->off == 0) stats_note(t - k->arrived, k->len); /* its first bytes left */
    k->off += (uint32_t)n;
    if (k->off < k->len) {
      q->blocked = 1; /* the socket took part: it is full */
      return 0;
    }
    queue_pop(q);
  }
  return 0;
}

/* An event on fd[s]. Returns -1 when the connection must close. */
static int conn_event(conn *c, int s, uint32_t ev) {
  if (ev & (EPOLLOUT | EPOLLERR) && s == 1 && !c->connected) {
    int err = 0;
    socklen_t len = sizeof(err);
    if (getsockopt(c->fd[1], SOL_SOCKET, SO_ERROR, &err, &len) != 0 || err != 0) return -1;
    c->connected = 1;
  }
  if (ev & EPOLLOUT) c->q[!s].blocked = 0;
  if (c->q[s].reading) return ev & (EPOLLIN | EPOLLHUP | EPOLLERR) ? conn_read(c, s) : 0;
  /* Past its end of stream, an fd reports hang-ups until it is closed.
   * Shut both ways (its end read, ours forwarded), it has nothing left
   * to do and leaves the epoll set, so as not to wake the loop while the
   * other direction's last chunks wait; an error ends the connection. */
  if (ev & EPOLLERR || (ev & EPOLLHUP && !c->q[!s].shut)) return -1;
  if (ev & EPOLLHUP) {
    c->mask[s] = GONE;
    return epoll_ctl(R.epfd, EPOLL_CTL_DEL, c->fd[s], NULL);
  }
  return 0;
}

/* ---- the loop ---------------------------------------------------------------- */

/* The time until the earliest chunk that can be written is due; NULL
 * (wait for an event) when none is. */
static struct timespec *next_timeout(struct timespec *ts) {
  uint64_t due = UINT64_MAX;
  for (conn *c = R.conns; c != NULL; c = c->next)
    for (int s = 0; s < 2; s++)
      if (c->connected && !c->q[s].blocked && c->q[s].head != NULL && c->q[s].head->due < due)
        due = c->q[s].head->due;
  if (due == UINT64_MAX) return NULL;
  uint64_t t = now_ns(), d = due > t ? due - t : 0;
  ts->tv_sec = (time_t)(d / 1000000000u);
  ts->tv_nsec = (long)(d % 1000000000u);
  return ts;
}

static void set_delay(double us) {
  R.delay_us = us;
  R.delay_ns = (uint64_t)(us * 1000 + 0.5);
}

/* One control line from stdin. */
static void control(const char *line) {
  char *end;
  if (strncmp(line, "delay ", 6) == 0) {
    double us = strtod(line + 6, &end);
    while (*end == ' ' || *end == '\n' || *end == '\r') end++;
    if (end == line + 6 || *end != '\0' || !(us >= 0 && us <= MAX_DELAY_US)) {
      printf("error: delay wants microseconds, 0..%.0f: %s", MAX_DELAY_US, line);
    } else {
      set_delay(us);
      printf("ok delay %.1f\n", us);
    }
  } else if (strcmp(line, "stats\n") == 0 || strcmp(line, "stats") == 0) {
    stats_print();
    return;
  } else {
    printf("error: unknown command (delay US | stats): %s", line);
  }
  fflush(stdout);
}

/* Reads whatever stdin holds and runs its complete lines. Returns -1 at
 * its end (the relay keeps running without a control channel). */
static int read_control(void) {
  static char line[256];
  static size_t have;
  ssize_t n = read(STDIN_FILENO, line + have, sizeof(line) - 1 - have);
  if (n <= 0) return n < 0 && errno == EAGAIN ? 0 : -1;
  have += (size_t)n;
  line[have] = '\0';
  char *nl;
  while ((nl = strchr(line, '\n')) != NULL) {
    char cmd[256];
    size_t len = (size_t)(nl - line) + 1;
    memcpy(cmd, line, len);
    cmd[len] = '\0';
    control(cmd);
    memmove(line, nl + 1, have - len + 1);
    have -= len;
  }
  if (have == sizeof(line) - 1) have = 0; /* a line too long for any command */
  return 0;
}

static void accept_all(void) {
  for (;;) {
    int fd = accept4(R.lfd, NULL, NULL, SOCK_NONBLOCK | SOCK_CLOEXEC);
    if (fd < 0) return;
    if (conn_open(fd) != 0) fprintf(stderr, "delay_relay: cannot forward a connection: %s\n", strerror(errno));
  }
}

static int run(int sigfd) {
  static endpoint gone = {NULL, -1};
  struct epoll_event evs[MAX_EVENTS];
  for (;;) {
    for (conn *c = R.conns, *n; c != NULL; c = n) {
      n = c->next;
      if (conn_flush(c, 0) != 0 || conn_flush(c, 1) != 0 || (c->q[0].shut && c->q[1].shut) ||
          conn_watch(c, 0) != 0 || conn_watch(c, 1) != 0)
        conn_close(c);
    }
    struct timespec ts;
    int n = epoll_pwait2(R.epfd, evs, MAX_EVENTS, next_timeout(&ts), NULL);
    if (n < 0 && errno != EINTR) return -1;
    for (int i = 0; i < n; i++) {
      endpoint *e = evs[i].data.ptr;
      if (e->c != NULL) {
        if (conn_event(e->c, e->side, evs[i].events) != 0) {
          conn *c = e->c;
          /* Its other endpoint may be later in this batch of events. */
          for (int j = i + 1; j < n; j++)
            if (((endpoint *)evs[j].data.ptr)->c == c) evs[j].data.ptr = &gone;
          conn_close(c);
        }
      } else if (e->side == EP_LISTEN) {
        accept_all();
      } else if (e->side == EP_STDIN) {
        if (read_control() != 0) epoll_ctl(R.epfd, EPOLL_CTL_DEL, STDIN_FILENO, NULL);
      } else if (e->side == EP_SIGNAL) {
        struct signalfd_siginfo si;
        if (read(sigfd, &si, sizeof(si)) == (ssize_t)sizeof(si)) return 0;
      }
    }
  }
}

/* ---- set-up ------------------------------------------------------------------ */

static int resolve(const char *arg, struct sockaddr_storage *ss, socklen_t *len) {
  char host[256];
  const char *colon = strrchr(arg, ':');
  if (colon == NULL || colon == arg || (size_t)(colon - arg) >= sizeof(host) || colon[1] == '\0') return -1;
  memcpy(host, arg, (size_t)(colon - arg));
  host[colon - arg] = '\0';
  struct addrinfo hints = {.ai_family = AF_UNSPEC, .ai_socktype = SOCK_STREAM}, *ai;
  if (getaddrinfo(host, colon + 1, &hints, &ai) != 0) return -1;
  memcpy(ss, ai->ai_addr, ai->ai_addrlen);
  *len = ai->ai_addrlen;
  freeaddrinfo(ai);
  return 0;
}

static int listen_on(const char *arg) {
  struct sockaddr_storage ss;
  socklen_t len;
  if (resolve(arg, &ss, &len) != 0) return -1;
  int fd = socket(ss.ss_family, SOCK_STREAM | SOCK_NONBLOCK | SOCK_CLOEXEC, 0), one = 1;
  if (fd < 0) return -1;
  setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
  if (bind(fd, (struct sockaddr *)&ss, len) != 0 || listen(fd, 64) != 0) {
    close(fd);
    return -1;
  }
  return fd;
}

static void print_address(int fd, const char *target) {
  struct sockaddr_storage ss;
  socklen_t len = sizeof(ss);
  char host[INET6_ADDRSTRLEN] = "?";
  int port = 0;
  getsockname(fd, (struct sockaddr *)&ss, &len);
  if (ss.ss_family == AF_INET) {
    struct sockaddr_in *a = (struct sockaddr_in *)&ss;
    inet_ntop(AF_INET, &a->sin_addr, host, sizeof(host));
    port = ntohs(a->sin_port);
  } else if (ss.ss_family == AF_INET6) {
    struct sockaddr_in6 *a = (struct sockaddr_in6 *)&ss;
    inet_ntop(AF_INET6, &a->sin6_addr, host, sizeof(host));
    port = ntohs(a->sin6_port);
  }
  printf("delay_relay: listening on %s:%d (forwarding to %s, %.1f us each way)\n", host, port, target, R.delay_us);
  fflush(stdout);
}

static int add_fd(int fd, int which) {
  static endpoint eps[3];
  eps[which] = (endpoint){NULL, which};
  struct epoll_event ev = {.events = EPOLLIN, .data.ptr = &eps[which]};
  return epoll_ctl(R.epfd, EPOLL_CTL_ADD, fd, &ev);
}

static void usage(FILE *f) {
  fprintf(f, "usage: delay_relay --listen HOST:PORT --target HOST:PORT [--delay-us US] [--fifo]\n"
             "  forwards every connection to TARGET, holding each chunk US microseconds\n"
             "  (default 0, max %.0f) in each direction; stdin takes 'delay US' and 'stats';\n"
             "  --fifo: real-time priority (SCHED_FIFO), so the delays end on time under load\n",
          MAX_DELAY_US);
}

int main(int argc, char **argv) {
  static const struct option opts[] = {{"listen", required_argument, 0, 'l'}, {"target", required_argument, 0, 't'},
                                       {"delay-us", required_argument, 0, 'd'}, {"fifo", no_argument, 0, 'f'},
                                       {"help", no_argument, 0, 'h'},
                                       {0, 0, 0, 0}};
  const char *listen_arg = NULL, *target_arg = NULL;
  int o, fifo = 0;
  while ((o = getopt_long(argc, argv, "", opts, NULL)) != -1) {
    char *end;
    double us;
    switch (o) {
    case 'l': listen_arg = optarg; break;
    case 't': target_arg = optarg; break;
    case 'd':
      us = strtod(optarg, &end);
      if (end == optarg || *end != '\0' || !(us >= 0 && us <= MAX_DELAY_US)) {
        fprintf(stderr, "delay_relay: --delay-us wants microseconds, 0..%.0f, not '%s'\n", MAX_DELAY_US, optarg);
        return 2;
      }
      set_delay(us);
      break;
    case 'f': fifo = 1; break;
    case 'h': usage(stdout); return 0;
    default: usage(stderr); return 2;
    }
  }
  if (listen_arg == NULL || target_arg == NULL || optind < argc) {
    usage(stderr);
    return 2;
  }
  if (resolve(target_arg, &R.target, &R.target_len) != 0) {
    fprintf(stderr, "delay_relay: cannot resolve --target '%s' (HOST:PORT)\n", target_arg);
    return 2;
  }
  R.lfd = listen_on(listen_arg);
  if (R.lfd < 0) {
    fprintf(stderr, "delay_relay: cannot listen on '%s': %s\n", listen_arg, strerror(errno));
    return 1;
  }
  /* Sleeps end when asked: no 50 us default slack on every timeout. */
  prctl(PR_SET_TIMERSLACK, 1UL, 0, 0, 0);
  struct sched_param sp = {.sched_priority = 1};
  if (fifo && sched_setscheduler(0, SCHED_FIFO, &sp) != 0) {
    fprintf(stderr, "delay_relay: --fifo: cannot run at real-time priority (%s): needs root\n", strerror(errno));
    return 1;
  }
  signal(SIGPIPE, SIG_IGN);
  sigset_t set;
  sigemptyset(&set);
  sigaddset(&set, SIGTERM);
  sigaddset(&set, SIGINT);
  sigprocmask(SIG_BLOCK, &set, NULL);
  int sigfd = signalfd(-1, &set, SFD_CLOEXEC);
  R.epfd = epoll_create1(EPOLL_CLOEXEC);
  if (sigfd < 0 || R.epfd < 0 || add_fd(R.lfd, EP_LISTEN) != 0 || add_fd(sigfd, EP_SIGNAL) != 0) {
    fprintf(stderr, "delay_relay: cannot set up epoll: %s\n", strerror(errno));
    return 1;
  }
  add_fd(STDIN_FILENO, EP_STDIN); /* optional: stdin may be a file or closed */
  print_address(R.lfd, target_arg);
  int rc = run(sigfd);
  stats_print();
  while (R.conns != NULL) conn_close(R.conns);
  return rc == 0 ? 0 : 1;
}
