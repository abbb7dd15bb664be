/* log.h - the daemons' log: one line per event on the stream set at
 * startup, "PROG: 2024-05-06T07:08:09Z message" (UTC). Everything a daemon
 * does (its own events, the cluster's, the job queue's) goes through here,
 * so every line looks the same and a test or an operator can grep one
 * file. Lines from several threads never mix: each is one write to a
 * stdio stream, which locks it. */
#ifndef TS_LOG_H
#define TS_LOG_H

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

#endif
