/* connset.c - see connset.h. */
#include "connset.h"

#include <sys/socket.h>

void ts_connset_init(ts_connset *s) {
  pthread_mutex_init(&s->lock, NULL);
  pthread_cond_init(&s->empty, NULL);
  s->n = 0;
}

int ts_connset_add(ts_connset *s, int fd) {
  pthread_mutex_lock(&s->lock);
  int ok = s->n < TS_CONNSET_MAX;
  if (ok) s->fds[s->n++] = fd;
  pthread_mutex_unlock(&s->lock);
  return ok ? 0 : -1;
}

void ts_connset_remove(ts_connset *s, int fd) {
  pthread_mutex_lock(&s->lock);
  for (int i = 0; i < s->n; i++)
    if (s->fds[i] == fd) {
      s->fds[i] = s->fds[--s->n];
      break;
    }
  if (s->n == 0) pthread_cond_broadcast(&s->empty);
  pthread_mutex_unlock(&s->lock);
}

void ts_connset_close_all(ts_connset *s) {
  pthread_mutex_lock(&s->lock);
  for (int i = 0; i < s->n; i++) shutdown(s->fds[i], SHUT_RDWR);
  while (s->n > 0) pthread_cond_wait(&s->empty, &s->lock);
  pthread_mutex_unlock(&s->lock);
}
