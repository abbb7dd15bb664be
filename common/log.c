/* log.c - see log.h. */
#include "log.h"

#include <stdarg.h>
#include <pthread.h>
#include <stddef.h>
#include <time.h>

static const char *g_prog = "texsyn";
static FILE *g_stream; /* NULL: stderr, which is no constant to start from */
static int g_quiet;

void ts_log_init(const char *prog, FILE *stream, int quiet) {
  g_prog = prog;
  g_stream = stream;
  g_quiet = quiet;
}

/* Copies msg with every control byte (newlines, escapes, DEL) written as
 * \xNN: a line may carry text from a peer that has not authenticated (its
 * 'E' message, its name), which must not forge log lines or drive the
 * reader's terminal. */
static void escape(const char *msg, char *out, size_t cap) {
  size_t o = 0;
  for (const unsigned char *p = (const unsigned char *)msg; *p != '\0' && o + 5 < cap; p++) {
    if (*p < 0x20 || *p == 0x7f) o += (size_t)snprintf(out + o, cap - o, "\\x%02x", *p);
    else out[o++] = (char)*p;
  }
  out[o] = '\0';
}

static void log_line(const char *fmt, va_list ap) __attribute__((format(printf, 1, 0)));
static void log_line(const char *fmt, va_list ap) {
  char raw[1200], msg[1200];
  vsnprintf(raw, sizeof(raw), fmt, ap);
  escape(raw, msg, sizeof(msg));
  time_t t = time(NULL);
  struct tm tm;
  gmtime_r(&t, &tm);
  fprintf(g_stream != NULL ? g_stream : stderr, "%s: %04d-%02d-%02dT%02d:%02d:%02dZ %s\n", g_prog,
          tm.tm_year + 1900, tm.tm_mon + 1, tm.tm_mday, tm.tm_hour, tm.tm_min, tm.tm_sec, msg);
}

void ts_log(const char *fmt, ...) {
  if (g_quiet) return;
  va_list ap;
  va_start(ap, fmt);
  log_line(fmt, ap);
  va_end(ap);
}

void ts_warn(const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  log_line(fmt, ap);
  va_end(ap);
}

void ts_warn_msg(const char *msg) { ts_warn("%s", msg); }

void ts_log_limited(ts_log_limit *l, const char *fmt, ...) {
  struct timespec now;
  clock_gettime(CLOCK_MONOTONIC, &now);
  double t = (double)now.tv_sec + now.tv_nsec * 1e-9;
  pthread_mutex_lock(&l->lock);
  unsigned long long held = l->held;
  int write = l->last == 0 || t - l->last >= TS_LOG_LIMIT_SECONDS;
  if (write) {
    l->last = t;
    l->held = 0;
  } else {
    l->held++;
  }
  pthread_mutex_unlock(&l->lock);
  if (!write) return;
  char msg[1000];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(msg, sizeof(msg), fmt, ap);
  va_end(ap);
  if (held > 0) ts_warn("%s (and %llu more like it since the last such line)", msg, held);
  else ts_warn("%s", msg);
}
