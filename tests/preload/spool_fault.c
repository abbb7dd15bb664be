/* spool_fault.c - an LD_PRELOAD shim for the spool's fault tests: it
 * numbers the calls that change files under a directory (the spool) and
 * kills the process at one of them, or makes them fail.
 *
 * The calls ("points"): open and fopen for writing, write, fflush (a
 * stream's buffered bytes going out), fsync and fdatasync, rename, mkdir,
 * unlink, unlinkat and rmdir, on a path under TEXSYN_SPOOL_FAULT_DIR (an
 * absolute path; a descriptor's path is read from /proc/self/fd). They
 * are numbered from 1 in the order the process makes them.
 *
 *   TEXSYN_SPOOL_FAULT_LOG=FILE   appends "N CALL PATH" to FILE for every
 *                                 point, " !WHAT" after it when acted on
 *   TEXSYN_SPOOL_FAULT_AT=N       the point to act on
 *   TEXSYN_SPOOL_FAULT=WHAT       kill: SIGKILL instead of the call, so
 *                                 the spool is left as it was before it;
 *                                 EACCES, EROFS, EIO or ENOSPC: the call
 *                                 is not made and fails with that errno
 *   TEXSYN_SPOOL_FAULT_WHILE=FILE the errno at every point while FILE
 *                                 exists (a disk that stays read-only
 *                                 until the test lets it heal)
 *
 * Built without sanitizers (Makefile): it is preloaded into the plain
 * build only. */
#include <dlfcn.h>
#include <errno.h>
#include <fcntl.h>
#include <limits.h>
#include <signal.h>
#include <stdarg.h>
#include <stdatomic.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#define REAL(name) ((__typeof__(&name))dlsym(RTLD_NEXT, #name))

static atomic_long points;

/* The errno a fault name stands for; 0 for kill or an unknown name. */
static int fault_errno(const char *what) {
  static const struct {
    const char *name;
    int code;
  } codes[] = {{"EACCES", EACCES}, {"EROFS", EROFS}, {"EIO", EIO}, {"ENOSPC", ENOSPC}};
  for (size_t i = 0; what != NULL && i < sizeof(codes) / sizeof(codes[0]); i++)
    if (strcmp(what, codes[i].name) == 0) return codes[i].code;
  return 0;
}

/* Whether path lies under the spool (the directory itself included). */
static int in_spool(const char *path) {
  const char *dir = getenv("TEXSYN_SPOOL_FAULT_DIR");
  if (dir == NULL || dir[0] != '/' || path == NULL) return 0;
  size_t n = strlen(dir);
  return strncmp(path, dir, n) == 0 && (path[n] == '\0' || path[n] == '/');
}

/* path made absolute against the working directory, into out. */
static const char *absolute(const char *path, char *out, size_t cap) {
  char cwd[PATH_MAX];
  if (path == NULL || path[0] == '/' || getcwd(cwd, sizeof(cwd)) == NULL) return path;
  snprintf(out, cap, "%s/%s", cwd, path);
  return out;
}

/* The path open as fd ("" if it has none), into out. */
static const char *fd_path(int fd, char *out, size_t cap) {
  char link[64];
  snprintf(link, sizeof(link), "/proc/self/fd/%d", fd);
  ssize_t n = readlink(link, out, cap - 1);
  out[n > 0 ? n : 0] = '\0';
  return out;
}

static void log_point(long n, const char *call, const char *path, const char *acted) {
  const char *file = getenv("TEXSYN_SPOOL_FAULT_LOG");
  if (file == NULL) return;
  char line[PATH_MAX + 96];
  int len = snprintf(line, sizeof(line), "%ld %s %s%s%s\n", n, call, path, acted ? " !" : "", acted ? acted : "");
  int fd = REAL(open)(file, O_WRONLY | O_CREAT | O_APPEND | O_CLOEXEC, 0644);
  if (fd < 0) return;
  ssize_t w = REAL(write)(fd, line, (size_t)len); /* a line lost shows as a gap in the numbers */
  (void)w;
  close(fd);
}

/* Counts a point on path; 0 to make the call, or -1 with errno set when
 * the fault says it fails (a kill does not return). */
static int point(const char *call, const char *path) {
  if (!in_spool(path)) return 0;
  long n = atomic_fetch_add(&points, 1) + 1;
  const char *what = getenv("TEXSYN_SPOOL_FAULT"), *at = getenv("TEXSYN_SPOOL_FAULT_AT");
  const char *while_file = getenv("TEXSYN_SPOOL_FAULT_WHILE");
  struct stat st;
  int hit = (at != NULL && atol(at) == n) || (while_file != NULL && stat(while_file, &st) == 0);
  if (!hit || what == NULL) {
    log_point(n, call, path, NULL);
    return 0;
  }
  log_point(n, call, path, what);
  if (strcmp(what, "kill") == 0) raise(SIGKILL);
  int code = fault_errno(what);
  if (code == 0) return 0;
  errno = code;
  return -1;
}

static int writing(int flags) { return (flags & (O_WRONLY | O_RDWR | O_CREAT | O_TRUNC)) != 0; }

static int open_point(const char *path, int flags) {
  char abs[2 * PATH_MAX];
  return writing(flags) ? point("open", absolute(path, abs, sizeof(abs))) : 0;
}

static int fd_point(const char *call, int fd) {
  char path[PATH_MAX];
  return point(call, fd_path(fd, path, sizeof(path)));
}

static int path_point(const char *call, const char *path) {
  char abs[2 * PATH_MAX];
  return point(call, absolute(path, abs, sizeof(abs)));
}

int open(const char *path, int flags, ...) {
  mode_t mode = 0;
  if (flags & (O_CREAT | O_TMPFILE)) {
    va_list ap;
    va_start(ap, flags);
    mode = va_arg(ap, mode_t);
    va_end(ap);
  }
  if (open_point(path, flags) != 0) return -1;
  return REAL(open)(path, flags, mode);
}

int open64(const char *path, int flags, ...) {
  mode_t mode = 0;
  if (flags & (O_CREAT | O_TMPFILE)) {
    va_list ap;
    va_start(ap, flags);
    mode = va_arg(ap, mode_t);
    va_end(ap);
  }
  if (open_point(path, flags) != 0) return -1;
  return REAL(open64)(path, flags, mode);
}

static int stream_writes(const char *mode) { return strpbrk(mode, "wa+") != NULL; }

FILE *fopen(const char *path, const char *mode) {
  char abs[2 * PATH_MAX];
  if (stream_writes(mode) && point("open", absolute(path, abs, sizeof(abs))) != 0) return NULL;
  return REAL(fopen)(path, mode);
}

FILE *fopen64(const char *path, const char *mode) {
  char abs[2 * PATH_MAX];
  if (stream_writes(mode) && point("open", absolute(path, abs, sizeof(abs))) != 0) return NULL;
  return REAL(fopen64)(path, mode);
}

ssize_t write(int fd, const void *buf, size_t len) {
  if (fd_point("write", fd) != 0) return -1;
  return REAL(write)(fd, buf, len);
}

int fflush(FILE *f) {
  if (f != NULL && fd_point("fflush", fileno(f)) != 0) return EOF;
  return REAL(fflush)(f);
}

int fsync(int fd) {
  if (fd_point("fsync", fd) != 0) return -1;
  return REAL(fsync)(fd);
}

int fdatasync(int fd) {
  if (fd_point("fsync", fd) != 0) return -1;
  return REAL(fdatasync)(fd);
}

int rename(const char *from, const char *to) {
  char abs[2 * PATH_MAX];
  const char *dest = absolute(to, abs, sizeof(abs));
  if (point("rename", in_spool(dest) ? dest : absolute(from, abs, sizeof(abs))) != 0) return -1;
  return REAL(rename)(from, to);
}

int mkdir(const char *path, mode_t mode) {
  if (path_point("mkdir", path) != 0) return -1;
  return REAL(mkdir)(path, mode);
}

int unlink(const char *path) {
  if (path_point("unlink", path) != 0) return -1;
  return REAL(unlink)(path);
}

int unlinkat(int dirfd, const char *name, int flags) {
  char dir[PATH_MAX], path[2 * PATH_MAX];
  const char *where = path;
  if (dirfd == AT_FDCWD || name[0] == '/') where = absolute(name, path, sizeof(path));
  else snprintf(path, sizeof(path), "%s/%s", fd_path(dirfd, dir, sizeof(dir)), name);
  if (point((flags & AT_REMOVEDIR) ? "rmdir" : "unlink", where) != 0) return -1;
  return REAL(unlinkat)(dirfd, name, flags);
}

int rmdir(const char *path) {
  if (path_point("rmdir", path) != 0) return -1;
  return REAL(rmdir)(path);
}
