/* connset.h - the open connections of a daemon that serves each one on its
 * own thread, so that shutdown can wake them all (shutdown(2) on every
 * socket) and wait until they are gone before freeing what they use. */
#ifndef TS_CONNSET_H
#define TS_CONNSET_H

#include <pthread.h>

#define TS_CONNSET_MAX 1024

typedef struct {
  pthread_mutex_t lock;
  pthread_cond_t empty;
  int fds[TS_CONNSET_MAX];
  int n;
} ts_connset;

void ts_connset_init(ts_connset *s);
/* 0, or -1 when TS_CONNSET_MAX connections are open. */
int ts_connset_add(ts_connset *s, int fd);
/* Call before closing fd (the number may be reused right after). */
void ts_connset_remove(ts_connset *s, int fd);
/* Shuts every socket down and waits for every remove. */
void ts_connset_close_all(ts_connset *s);

#endif
