/* util.c - see util.h. */
#include "util.h"

#include <stdarg.h>

#include <errno.h>
#include <fcntl.h>
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "error.h"

double ts_now(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec + ts.tv_nsec * 1e-9;
}

uint64_t ts_clock_ms(void) {
  struct timespec ts;
  clock_gettime(CLOCK_REALTIME, &ts);
  return (uint64_t)ts.tv_sec * 1000u + (uint64_t)(ts.tv_nsec / 1000000);
}

struct timespec ts_wait_until(double seconds) {
  struct timespec ts;
  clock_gettime(CLOCK_REALTIME, &ts);
  double whole = floor(seconds);
  ts.tv_sec += (time_t)whole;
  ts.tv_nsec += (long)((seconds - whole) * 1e9);
  if (ts.tv_nsec >= 1000000000L) {
    ts.tv_sec++;
    ts.tv_nsec -= 1000000000L;
  }
  return ts;
}

/* ---- whole files ---------------------------------------------------------- */

/* Reads exactly n bytes from fd into buf. */
static int read_exact(int fd, uint8_t *buf, size_t n, const char *path, char *err) {
  for (size_t got = 0; got < n;) {
    ssize_t k = read(fd, buf + got, n - got);
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0)
      return ts_error(err, TS_EIO, "cannot read %s: %s", path,
                      k < 0 ? strerror(errno) : "the file shrank while being read");
    got += (size_t)k;
  }
  return 0;
}

/* The size of the regular file open as fd, checked against max_bytes. */
static int file_size(int fd, const char *path, size_t max_bytes, size_t *len, char *err) {
  struct stat st;
  if (fstat(fd, &st) != 0) return ts_error(err, TS_EIO, "cannot read %s: %s", path, strerror(errno));
  if (!S_ISREG(st.st_mode)) return ts_error(err, TS_EIO, "cannot read %s: not a regular file", path);
  uint64_t size = (uint64_t)st.st_size;
  if (size >= SIZE_MAX) return ts_error(err, TS_ENOMEM, "%s: %llu bytes do not fit in memory", path,
                                        (unsigned long long)size);
  *len = (size_t)size;
  if (size > max_bytes)
    return ts_error(err, TS_ETOOBIG, "%s: %llu bytes, over the limit of %zu", path,
                    (unsigned long long)size, max_bytes);
  return 0;
}

int ts_file_read(const char *path, size_t max_bytes, uint8_t **buf, size_t *len, char *err) {
  *buf = NULL;
  *len = 0;
  int fd = open(path, O_RDONLY | O_CLOEXEC);
  if (fd < 0) return ts_error(err, TS_EIO, "cannot read %s: %s", path, strerror(errno));
  int rc = file_size(fd, path, max_bytes, len, err);
  uint8_t *b = NULL;
  if (rc == 0 && (b = malloc(*len + 1)) == NULL)
    rc = ts_error(err, TS_ENOMEM, "out of memory reading %s (%zu bytes)", path, *len);
  if (rc == 0) rc = read_exact(fd, b, *len, path, err);
  close(fd);
  if (rc != 0) {
    free(b);
    if (rc != TS_ETOOBIG) *len = 0;
    return rc;
  }
  b[*len] = '\0';
  *buf = b;
  return 0;
}

/* ---- numbers -------------------------------------------------------------- */

int ts_parse_long(const char *text, long lo, long hi, long *out) {
  char *end;
  errno = 0;
  long v = strtol(text, &end, 10);
  if (errno != 0 || end == text || *end != '\0' || v < lo || v > hi) return TS_EINVAL;
  *out = v;
  return 0;
}

int ts_parse_int(const char *text, int lo, int hi, int *out) {
  long v;
  if (ts_parse_long(text, lo, hi, &v) != 0) return TS_EINVAL;
  *out = (int)v;
  return 0;
}

int ts_parse_u64(const char *text, uint64_t *out) {
  char *end;
  errno = 0;
  unsigned long long v = strtoull(text, &end, 10);
  /* strtoull takes "-1" as 2^64-1; a count is never negative. */
  if (errno != 0 || end == text || *end != '\0' || strchr(text, '-') != NULL) return TS_EINVAL;
  *out = v;
  return 0;
}

int ts_parse_bytes(const char *text, uint64_t *out) {
  char *end;
  errno = 0;
  double v = strtod(text, &end);
  const char *units = "KMGT";
  const char *u = *end ? strchr(units, *end) : NULL;
  if (u != NULL && end[1] == '\0') v *= (double)(1ull << (10 * (u - units + 1)));
  if (errno != 0 || end == text || (*end != '\0' && (u == NULL || end[1] != '\0')) || !(v >= 0 && v < 9.2e18))
    return TS_EINVAL;
  *out = (uint64_t)v;
  return 0;
}

int ts_parse_double(const char *text, double *out) {
  char *end;
  errno = 0;
  double v = strtod(text, &end);
  if (errno != 0 || end == text || *end != '\0' || !isfinite(v)) return TS_EINVAL;
  *out = v;
  return 0;
}

int ts_parse_size(const char *text, int max, int *w, int *h) {
  char *end;
  long a = strtol(text, &end, 10);
  if (end == text || (*end != 'x' && *end != 'X')) return TS_EFORMAT;
  long b;
  /* An overflowing W comes back as LONG_MAX or LONG_MIN: out of range. */
  if (a < 1 || a > max || ts_parse_long(end + 1, 1, max, &b) != 0) return TS_EINVAL;
  *w = (int)a;
  *h = (int)b;
  return 0;
}

/* The temporary name beside path that ts_file_create and ts_file_write
 * write under: the pid keeps two processes writing one path apart. */
static int temporary_path(const char *path, char *tmp, char *err) {
  int n = snprintf(tmp, TS_FILE_TMP_LEN, "%s.tmp-%ld", path, (long)getpid());
  if (n < 0 || n >= TS_FILE_TMP_LEN) return ts_error(err, TS_EIO, "cannot write %s: path too long", path);
  return 0;
}

FILE *ts_file_create(const char *path, char *tmp, char *err) {
  if (temporary_path(path, tmp, err) != 0) return NULL;
  FILE *f = fopen(tmp, "wb");
  if (f == NULL) ts_error(err, TS_EIO, "cannot write %s: %s", path, strerror(errno));
  return f;
}

int ts_dir_sync(const char *dir) {
  int fd = open(dir, O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) return -1;
  /* EINVAL: a file system that has nothing to sync for a directory. */
  int rc = fsync(fd) != 0 && errno != EINVAL ? -1 : 0;
  int e = errno;
  close(fd);
  errno = e;
  return rc;
}

int ts_parent_sync(const char *path) {
  char dir[TS_FILE_TMP_LEN];
  const char *slash = strrchr(path, '/');
  if (slash == NULL) return ts_dir_sync(".");
  size_t n = slash == path ? 1 : (size_t)(slash - path);
  if (n >= sizeof(dir)) {
    errno = ENAMETOOLONG;
    return -1;
  }
  memcpy(dir, path, n);
  dir[n] = '\0';
  return ts_dir_sync(dir);
}

/* The end of every atomic write, once the temporary file's bytes are
 * synced and it is closed (ok, else e is why not): the bytes reach the disk
 * before the name does (fsync, then rename), and the name before the caller
 * goes on (the directory's fsync): a caller that records "done" after its
 * results, or acknowledges a file, can rely on what it recorded surviving a
 * power loss, never naming an empty or half-written file. */
static int file_publish(const char *tmp, const char *path, int ok, int e, char *err) {
  if (ok && rename(tmp, path) != 0) {
    ok = 0;
    e = errno;
  }
  if (!ok) {
    unlink(tmp);
    return ts_error(err, TS_EIO, "cannot write %s: %s", path, strerror(e));
  }
  if (ts_parent_sync(path) != 0)
    return ts_error(err, TS_EIO, "cannot write %s: syncing its directory: %s", path, strerror(errno));
  return 0;
}

int ts_file_commit(FILE *f, const char *tmp, const char *path, int ok, char *err) {
  if (ok && (fflush(f) != 0 || ferror(f) || fsync(fileno(f)) != 0)) ok = 0;
  int e = errno;
  if (fclose(f) != 0 && ok) {
    ok = 0;
    e = errno;
  }
  return file_publish(tmp, path, ok, e, err);
}

/* Bytes in memory go out by write() itself, with no stream's buffer
 * between: one call for a regular file, however large. */
int ts_file_write(const char *path, const void *data, size_t len, char *err) {
  char tmp[TS_FILE_TMP_LEN];
  if (temporary_path(path, tmp, err) != 0) return TS_EIO;
  int fd = open(tmp, O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0666);
  if (fd < 0) return ts_error(err, TS_EIO, "cannot write %s: %s", path, strerror(errno));
  const uint8_t *p = data;
  int ok = 1, e = 0;
  for (size_t left = len; ok && left > 0;) {
    ssize_t k = write(fd, p, left);
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0) {
      ok = 0;
      e = k < 0 ? errno : ENOSPC; /* a regular file that takes no byte is full */
    } else {
      p += k;
      left -= (size_t)k;
    }
  }
  if (ok && fsync(fd) != 0) {
    ok = 0;
    e = errno;
  }
  if (close(fd) != 0 && ok) {
    ok = 0;
    e = errno;
  }
  return file_publish(tmp, path, ok, e, err);
}

static void problem_v(char *msg, size_t len, int *count, const char *fmt, va_list ap) {
  size_t used = strlen(msg);
  (*count)++;
  if (used + 4 >= len) return;
  if (used > 0) msg[used++] = '\n';
  vsnprintf(msg + used, len - used, fmt, ap);
}

void ts_problem(char *msg, size_t len, int *count, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  problem_v(msg, len, count, fmt, ap);
  va_end(ap);
}

void ts_problems_add(ts_problems *pr, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  problem_v(pr->msg, pr->len, &pr->count, fmt, ap);
  va_end(ap);
}
