/* replay.c - a main() for a libFuzzer target without libFuzzer: feeds every
 * file named on the command line (directories: every regular file in them,
 * sorted) to LLVMFuzzerTestOneInput once. Built with the normal compiler
 * into BUILD/tests/replay_<target>, so `make test` replays the committed
 * seeds and crash regressions (tests/fuzz/seeds, tests/fuzz/regress) on
 * every build, sanitized or not, with no clang. A bug shows as a crash or
 * a sanitizer report; exit 0 and one summary line otherwise. */
#include <dirent.h>
#include <errno.h>
#include <limits.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "error.h"
#include "util.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);
/* Optional, as for libFuzzer: called once before any input if defined. */
int LLVMFuzzerInitialize(int *argc, char ***argv) __attribute__((weak));

static int replay_file(const char *path) {
  uint8_t *buf;
  size_t len;
  char err[TS_ERR_LEN];
  if (ts_file_read(path, SIZE_MAX, &buf, &len, err) != 0) {
    fprintf(stderr, "replay: %s\n", err);
    return -1;
  }
  /* An exact-size copy, so that reading past the input is caught. */
  uint8_t *exact = malloc(len ? len : 1);
  if (exact == NULL) {
    free(buf);
    return -1;
  }
  memcpy(exact, buf, len);
  free(buf);
  LLVMFuzzerTestOneInput(exact, len);
  free(exact);
  return 0;
}

static int by_name(const void *a, const void *b) {
  return strcmp(*(char *const *)a, *(char *const *)b);
}

/* Replays the regular files of dir in name order; -1 on any failure. */
static int replay_dir(const char *dir, int *count) {
  DIR *d = opendir(dir);
  if (d == NULL) {
    fprintf(stderr, "replay: %s: %s\n", dir, strerror(errno));
    return -1;
  }
  char **names = NULL;
  size_t n = 0, cap = 0;
  int rc = 0;
  struct dirent *e;
  while ((e = readdir(d)) != NULL) {
    if (e->d_name[0] == '.') continue;
    if (n == cap) {
      cap = cap ? cap * 2 : 64;
      char **p = realloc(names, cap * sizeof(*names));
      if (p == NULL) {
        rc = -1;
        break;
      }
      names = p;
    }
    if ((names[n] = strdup(e->d_name)) == NULL) {
      rc = -1;
      break;
    }
    n++;
  }
  closedir(d);
  if (n > 0) qsort(names, n, sizeof(*names), by_name);
  for (size_t i = 0; i < n; i++) {
    char path[PATH_MAX];
    struct stat st;
    snprintf(path, sizeof(path), "%s/%s", dir, names[i]);
    if (rc == 0 && stat(path, &st) == 0 && S_ISREG(st.st_mode)) {
      if (replay_file(path) != 0) rc = -1;
      else (*count)++;
    }
    free(names[i]);
  }
  free(names);
  return rc;
}

int main(int argc, char **argv) {
  int count = 0, rc = 0;
  if (LLVMFuzzerInitialize != NULL) LLVMFuzzerInitialize(&argc, &argv);
  for (int i = 1; i < argc; i++) {
    struct stat st;
    if (stat(argv[i], &st) != 0) {
      fprintf(stderr, "replay: %s: %s\n", argv[i], strerror(errno));
      rc = 1;
    } else if (S_ISDIR(st.st_mode)) {
      if (replay_dir(argv[i], &count) != 0) rc = 1;
    } else if (replay_file(argv[i]) != 0) {
      rc = 1;
    } else {
      count++;
    }
  }
  printf("replay: %d inputs%s\n", count, rc ? ", some unreadable" : "");
  return rc;
}
