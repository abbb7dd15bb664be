/* util.h - small helpers every layer uses: the monotonic clock, whole-file
 * reads, numeric option parsing. One copy each, here. */
#ifndef TS_UTIL_H
#define TS_UTIL_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <time.h>

/* Seconds on the monotonic clock (for durations and deadlines only). */
double ts_now(void);

/* Milliseconds since the epoch on the realtime clock: when something
 * happened, as a restart or another host can read it. */
uint64_t ts_clock_ms(void);

/* The moment `seconds` from now on the realtime clock, as
 * pthread_cond_timedwait takes it. */
struct timespec ts_wait_until(double seconds);

/* Appends a problem to a list of them in msg (len bytes), one a line, and
 * counts it in *count: checks that report every problem at once. */
void ts_problem(char *msg, size_t len, int *count, const char *fmt, ...) __attribute__((format(printf, 4, 5)));
/* The same for checkers that pass their problems along: msg (len bytes,
 * a string), and how many problems there were. */
typedef struct {
  char *msg;
  size_t len;
  int count;
} ts_problems;
void ts_problems_add(ts_problems *pr, const char *fmt, ...) __attribute__((format(printf, 2, 3)));

/* Reads the regular file at path whole into a malloc'd buffer: *buf holds
 * *len bytes and a NUL after them, so text can be used as a string.
 * Files over max_bytes are refused (SIZE_MAX: no limit but memory). 0, or
 * with a message naming the file: TS_EIO (cannot open or read it, or not a
 * regular file), TS_ETOOBIG (*len is then the file's size, for a caller
 * that says why the limit is there), TS_ENOMEM. */
int ts_file_read(const char *path, size_t max_bytes, uint8_t **buf, size_t *len, char *err);

/* A file written whole or not at all, so a reader never sees half of it:
 * ts_file_create opens a temporary file beside path (its name in tmp,
 * TS_FILE_TMP_LEN bytes), ts_file_commit closes it and renames it over
 * path - or removes it, when ok is 0 or anything fails. It is durable when
 * ts_file_commit returns: the file is fsynced before the rename and its
 * directory after. NULL / TS_EIO with a message naming path and the
 * system's reason. ts_file_write does both for bytes in memory: the one
 * atomic write of the project, the spool's files included. */
#define TS_FILE_TMP_LEN 4096
FILE *ts_file_create(const char *path, char *tmp, char *err);
int ts_file_commit(FILE *f, const char *tmp, const char *path, int ok, char *err);
int ts_file_write(const char *path, const void *data, size_t len, char *err);

/* Makes the names in directory dir durable (files created, renamed or
 * removed in it, directories made in it): fsync of the directory itself.
 * ts_parent_sync does it for the directory holding path. 0, or -1 with
 * errno set. */
int ts_dir_sync(const char *dir);
int ts_parent_sync(const char *path);

/* Numbers in option values and job specs: the whole text is one decimal
 * number (leading white space and a '+' are taken, as strtol does), else
 * TS_EINVAL and *out is left alone. No messages: each caller names its
 * option. */

/* A whole number in lo..hi. */
int ts_parse_long(const char *text, long lo, long hi, long *out);
int ts_parse_int(const char *text, int lo, int hi, int *out);
/* A whole number in 0..2^64-1; a minus sign is refused, not wrapped. */
int ts_parse_u64(const char *text, uint64_t *out);
/* A byte count with an optional binary suffix K, M, G or T (512, 64K,
 * 1.5G), below 2^63. */
int ts_parse_bytes(const char *text, uint64_t *out);
/* A finite number (strtod syntax: 2, 0.5, 1e-3); values too large or too
 * small for a double are refused. */
int ts_parse_double(const char *text, double *out);
/* A size "WxH" (or "WXH"), each 1..max. TS_EFORMAT if text does not start
 * with a number and an x at all, TS_EINVAL if the numbers are wrong (H
 * missing or not a number, either out of range): a caller can tell "not a
 * size" from "a size out of range". */
int ts_parse_size(const char *text, int max, int *w, int *h);

#endif
