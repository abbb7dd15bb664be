/* log.c - see log.h. */
#include "log.h"

#include <stdarg.h>
#include <time.h>

static const char *g_prog = "texsyn";
static FILE *g_stream; /* NULL: stderr, which is no constant to start from */
static int g_quiet;

void ts_log_init(const char *prog, FILE *stream, int quiet) {
  g_prog = prog;
  g_stream = stream;
  g_quiet = quiet;
}

static void log_line(const char *fmt, va_list ap) __attribute__((format(printf, 1, 0)));
static void log_line(const char *fmt, va_list ap) {
  char msg[1200];
  vsnprintf(msg, sizeof(msg), fmt, ap);
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
