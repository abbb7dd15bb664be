/* http_deadline.c - see http_deadline.h. */
#include "http_deadline.h"

#include <pthread.h>
#include <stdlib.h>
#include <sys/socket.h>

#include "error.h"
#include "log.h"
#include "util.h"

/* One open connection. Entries live from libmicrohttpd's STARTED to its
 * CLOSED notice, which comes before it closes the socket: under the lock
 * the fd is this connection's, never a number given to another. */
typedef struct conn {
  int fd;
  double since; /* connected, or its last response sent */
  int in;       /* a whole request is being answered */
  int shut;
  struct conn *next;
} conn;

static struct {
  pthread_mutex_t lock;
  pthread_cond_t wake;
  conn *head;
  double seconds;
  int running, stop;
  pthread_t thread;
} g = {PTHREAD_MUTEX_INITIALIZER, PTHREAD_COND_INITIALIZER, NULL, 0, 0, 0, 0};

static conn *of(struct MHD_Connection *c) {
  const union MHD_ConnectionInfo *ci = MHD_get_connection_info(c, MHD_CONNECTION_INFO_SOCKET_CONTEXT);
  return ci != NULL ? ci->socket_context : NULL;
}

void ts_http_deadline_notify(void *cls, struct MHD_Connection *c, void **socket_context,
                             enum MHD_ConnectionNotificationCode toe) {
  (void)cls;
  if (toe == MHD_CONNECTION_NOTIFY_STARTED) {
    const union MHD_ConnectionInfo *ci = MHD_get_connection_info(c, MHD_CONNECTION_INFO_CONNECTION_FD);
    conn *e = ci != NULL ? calloc(1, sizeof(*e)) : NULL;
    if (e == NULL) return; /* untracked: the idle timeout still holds */
    e->fd = ci->connect_fd;
    e->since = ts_now();
    pthread_mutex_lock(&g.lock);
    e->next = g.head;
    g.head = e;
    pthread_mutex_unlock(&g.lock);
    *socket_context = e;
    return;
  }
  conn *e = *socket_context;
  if (e == NULL) return;
  pthread_mutex_lock(&g.lock);
  conn **p = &g.head;
  while (*p != NULL && *p != e) p = &(*p)->next;
  if (*p != NULL) *p = e->next;
  pthread_mutex_unlock(&g.lock);
  free(e);
  *socket_context = NULL;
}

void ts_http_deadline_request_in(struct MHD_Connection *c) {
  conn *e = of(c);
  if (e == NULL) return;
  pthread_mutex_lock(&g.lock);
  e->in = 1;
  pthread_mutex_unlock(&g.lock);
}

void ts_http_deadline_completed(void *cls, struct MHD_Connection *c, void **con_cls,
                                enum MHD_RequestTerminationCode toe) {
  (void)cls, (void)con_cls, (void)toe;
  conn *e = of(c);
  if (e == NULL) return;
  pthread_mutex_lock(&g.lock);
  e->in = 0;
  e->since = ts_now(); /* a kept-alive connection's next request has its own time */
  pthread_mutex_unlock(&g.lock);
}

/* Shuts down the connections past their deadline (lock held); how many. */
static int reap(double now) {
  int n = 0;
  for (conn *e = g.head; e != NULL; e = e->next)
    if (!e->in && !e->shut && now - e->since > g.seconds) {
      shutdown(e->fd, SHUT_RDWR);
      e->shut = 1;
      n++;
    }
  return n;
}

static void *watch(void *arg) {
  (void)arg;
  pthread_mutex_lock(&g.lock);
  while (!g.stop) {
    struct timespec ts = ts_wait_until(0.5);
    pthread_cond_timedwait(&g.wake, &g.lock, &ts);
    int n = reap(ts_now());
    if (n > 0) {
      pthread_mutex_unlock(&g.lock); /* the log may block; connections must not */
      ts_log("http: closed %d connection%s that sent no whole request within %.0f s", n, n == 1 ? "" : "s",
             g.seconds);
      pthread_mutex_lock(&g.lock);
    }
  }
  pthread_mutex_unlock(&g.lock);
  return NULL;
}

int ts_http_deadline_start(double seconds, char *err) {
  g.seconds = seconds;
  g.stop = 0;
  if (pthread_create(&g.thread, NULL, watch, NULL) != 0) return ts_error(err, TS_ENOMEM, "cannot start a thread");
  g.running = 1;
  return 0;
}

void ts_http_deadline_stop(void) {
  if (!g.running) return;
  pthread_mutex_lock(&g.lock);
  g.stop = 1;
  pthread_cond_signal(&g.wake);
  pthread_mutex_unlock(&g.lock);
  pthread_join(g.thread, NULL);
  g.running = 0;
}
