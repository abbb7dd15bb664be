/* log.h - the daemons' log: one line per event on the stream set at
 * startup, "PROG: 2024-05-06T07:08:09Z message" (UTC). Everything a daemon
 * does (its own events, the cluster's, the job queue's) goes through here,
 * so every line looks the same and a test or an operator can grep one
 * file. Lines from several threads never mix: each is one write to a
 * stdio stream, which locks it. */
#ifndef TS_LOG_H
#define TS_LOG_H

#include <pthread.h>
#include <stdio.h>

/* Sets the program name, the stream and whether ts_log lines are dropped
 * (--quiet). Called once by main before any thread starts; until then
 * lines go to stderr as "texsyn: ...". */
void ts_log_init(const char *prog, FILE *stream, int quiet);

/* An event: dropped when quiet. */
void ts_log(const char *fmt, ...) __attribute__((format(printf, 1, 2)));

/* Something a user must fix (a refused peer, a failed join): written even
 * when quiet. */
void ts_warn(const char *fmt, ...) __attribute__((format(printf, 1, 2)));

/* ts_warn("%s", msg), for the log callbacks of the Modbus planes. */
void ts_warn_msg(const char *msg);

/* Lines a stranger can cause by the thousand (connections refused at a
 * limit, starts that time out): one limiter writes at most one line per
 * TS_LOG_LIMIT_SECONDS, and counts the others into the next line it
 * writes ("... (and 1984 more like it since the last such line)"). Written
 * even when quiet. */
#define TS_LOG_LIMIT_SECONDS 10.0
typedef struct {
  pthread_mutex_t lock;
  double last;
  unsigned long long held;
} ts_log_limit;
#define TS_LOG_LIMIT_INIT {PTHREAD_MUTEX_INITIALIZER, 0, 0}
void ts_log_limited(ts_log_limit *l, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

#endif
