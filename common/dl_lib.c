/* dl_lib.c - see dl_lib.h. */
#include "dl_lib.h"

#include <dlfcn.h>
#include <limits.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "error.h"

/* Loads the library at path and finds its table. */
static int dl_open(ts_dl_lib *lib, const char *path, const char *found_by, char *err) {
  void *h = dlopen(path, RTLD_NOW | RTLD_LOCAL);
  if (h == NULL)
    return ts_error(err, TS_ENOTSUP, "cannot load the %s %s (%s): %s", lib->what, path, found_by, dlerror());
  const void *t = dlsym(h, lib->name);
  if (t == NULL) {
    int rc = ts_error(err, TS_ENOTSUP,
                      "%s (%s) is not the %s of this texsyn build: %s; rebuild and reinstall both", path,
                      found_by, lib->what, dlerror());
    dlclose(h);
    return rc;
  }
  lib->table = t;
  return 0;
}

static int dl_find(ts_dl_lib *lib, char *err) {
  const char *env = getenv(lib->env);
  if (env != NULL && *env != '\0') {
    char by[64];
    snprintf(by, sizeof(by), "set by %s", lib->env);
    return dl_open(lib, env, by, err);
  }
  char dir[PATH_MAX];
  ssize_t n = readlink("/proc/self/exe", dir, sizeof(dir));
  if (n <= 0 || (size_t)n >= sizeof(dir) || dir[0] != '/')
    return ts_error(err, TS_ENOTSUP,
                    "cannot find the %s %s: /proc/self/exe does not name this program, so its directory "
                    "is unknown; set %s to the library's path",
                    lib->what, lib->file, lib->env);
  dir[n] = '\0';
  *strrchr(dir, '/') = '\0';
  static const struct {
    const char *sub, *found_by;
  } where[] = {{"", "next to the executable"}, {"/../lib/texsyn", "the install directory"}};
  char tried[2][PATH_MAX + 64]; /* room for dir, a sub-directory and the name */
  for (size_t i = 0; i < sizeof(where) / sizeof(where[0]); i++) {
    snprintf(tried[i], sizeof(tried[i]), "%s%s/%s", dir, where[i].sub, lib->file);
    if (access(tried[i], F_OK) == 0) return dl_open(lib, tried[i], where[i].found_by, err);
  }
  return ts_error(err, TS_ENOTSUP,
                  "%s not found: neither %s nor %s exists; build it (make) or install it (make install), "
                  "or set %s to its path",
                  lib->what, tried[0], tried[1], lib->env);
}

int ts_dl_lib_load(ts_dl_lib *lib, char *err) {
  static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
  pthread_mutex_lock(&lock);
  if (!lib->loaded) {
    lib->rc = dl_find(lib, lib->err);
    lib->loaded = 1;
  }
  pthread_mutex_unlock(&lock);
  return lib->rc != 0 ? ts_error(err, lib->rc, "%s", lib->err) : 0;
}
