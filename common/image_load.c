/* image_load.c - image.h's file functions in the programs: each loads
 * libtexsyn-image.so on first use and forwards through its table (see
 * image_lib.h for why the image code is a library of its own).
 *
 * The library is looked for, in this order:
 *   1. $TEXSYN_IMAGE_LIB, if set: that path only (tests and unusual
 *      installs; a wrong override must fail, not fall back to another
 *      library);
 *   2. next to the running executable (build/ in the source tree);
 *   3. ../lib/texsyn/ from the executable's directory, where `make install`
 *      puts it (PREFIX/bin/texsyn, PREFIX/lib/texsyn/libtexsyn-image.so):
 *      relative, so an installed tree can move.
 * A candidate that is there but does not load ends the search with its
 * reason: a broken library must be seen, not skipped for another one.
 *
 * Loaded with RTLD_NOW, so that a library built against another
 * OpenImageIO fails here with a message rather than killing the process at
 * its first unbound call; RTLD_LOCAL keeps its symbols out of the
 * programs' namespace. Never unloaded: its functions may run on any thread
 * until exit, and OpenImageIO's thread pools and C++ statics do not
 * unload cleanly (leak checkers also need its symbols to stay mapped). */
#include "image_lib.h"

#include <dlfcn.h>
#include <limits.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "error.h"
#include "image_meta.h"

/* The outcome of the one load, written only by ts_lib_load_once. */
static pthread_once_t ts_lib_once = PTHREAD_ONCE_INIT;
static const ts_image_lib *ts_lib;
static int ts_lib_rc;
static char ts_lib_err[TS_ERR_LEN];

/* Loads the library at path and finds its table. */
static int ts_lib_open(const char *path, const char *found_by, char *err) {
  void *h = dlopen(path, RTLD_NOW | RTLD_LOCAL);
  if (h == NULL)
    return ts_error(err, TS_ENOTSUP, "cannot load the image library %s (%s): %s", path, found_by,
                    dlerror());
  const ts_image_lib *table = dlsym(h, TS_IMAGE_LIB_TABLE_NAME);
  if (table == NULL) {
    int rc = ts_error(err, TS_ENOTSUP,
                      "%s (%s) is not an image library of this texsyn build: %s; rebuild and "
                      "reinstall both",
                      path, found_by, dlerror());
    dlclose(h);
    return rc;
  }
  ts_lib = table;
  return 0;
}

static void ts_lib_load_once(void) {
  const char *env = getenv(TS_IMAGE_LIB_ENV);
  if (env != NULL && *env != '\0') {
    ts_lib_rc = ts_lib_open(env, "set by " TS_IMAGE_LIB_ENV, ts_lib_err);
    return;
  }
  char dir[PATH_MAX];
  ssize_t n = readlink("/proc/self/exe", dir, sizeof(dir));
  if (n <= 0 || (size_t)n >= sizeof(dir) || dir[0] != '/') {
    ts_lib_rc = ts_error(ts_lib_err, TS_ENOTSUP,
                         "cannot find the image library " TS_IMAGE_LIB_NAME
                         ": /proc/self/exe does not name this program, so its directory is "
                         "unknown; set " TS_IMAGE_LIB_ENV " to the library's path");
    return;
  }
  dir[n] = '\0';
  *strrchr(dir, '/') = '\0';
  static const struct {
    const char *sub, *found_by;
  } where[] = {{"", "next to the executable"}, {"/../lib/texsyn", "the install directory"}};
  char tried[2][PATH_MAX + 64]; /* room for dir, a sub-directory and the name */
  for (size_t i = 0; i < sizeof(where) / sizeof(where[0]); i++) {
    snprintf(tried[i], sizeof(tried[i]), "%s%s/" TS_IMAGE_LIB_NAME, dir, where[i].sub);
    if (access(tried[i], F_OK) == 0) {
      ts_lib_rc = ts_lib_open(tried[i], where[i].found_by, ts_lib_err);
      return;
    }
  }
  ts_lib_rc = ts_error(ts_lib_err, TS_ENOTSUP,
                       "image library not found: neither %s nor %s exists; build it (make) or "
                       "install it (make install), or set " TS_IMAGE_LIB_ENV " to its path",
                       tried[0], tried[1]);
}

int ts_image_lib_load(char *err) {
  pthread_once(&ts_lib_once, ts_lib_load_once);
  return ts_lib_rc != 0 ? ts_error(err, ts_lib_rc, "%s", ts_lib_err) : 0;
}

/* --- image.h's file functions, forwarded -------------------------------- */

int ts_image_read(const char *path, ts_image *img, const ts_image_limits *limits, char *err) {
  if (img != NULL) memset(img, 0, sizeof(*img)); /* freeable even if nothing loads */
  int rc = ts_image_lib_load(err);
  return rc != 0 ? rc : ts_lib->read(path, img, limits, err);
}

int ts_image_read_mem(const char *name, const void *data, size_t len, ts_image *img,
                      const ts_image_limits *limits, char *err) {
  if (img != NULL) memset(img, 0, sizeof(*img));
  int rc = ts_image_lib_load(err);
  return rc != 0 ? rc : ts_lib->read_mem(name, data, len, img, limits, err);
}

int ts_image_probe_mem(const char *name, const void *data, size_t len,
                       const ts_image_limits *limits, ts_image_info *info, char *err) {
  int rc = ts_image_lib_load(err);
  return rc != 0 ? rc : ts_lib->probe_mem(name, data, len, limits, info, err);
}

int ts_image_write(const char *path, const ts_image *img, const ts_meta *meta_from, char *err) {
  int rc = ts_image_lib_load(err);
  return rc != 0 ? rc : ts_lib->write(path, img, meta_from, err);
}

/* Metadata only ever comes from the library: with some at hand it is
 * loaded; with none there is nothing to look up or free, and nothing is
 * loaded (every ts_image_free of an image without metadata lands in
 * ts_meta_free). */
int ts_meta_get(const ts_meta *meta, const char *name, char *out, size_t outlen) {
  if (meta == NULL || ts_image_lib_load(NULL) != 0) return TS_ENOENT;
  return ts_lib->meta_get(meta, name, out, outlen);
}

void ts_meta_free(ts_meta *meta) {
  if (meta != NULL && ts_image_lib_load(NULL) == 0) ts_lib->meta_free(meta);
}

int ts_meta_set(ts_meta **meta, const char *name, const char *value) {
  int rc = ts_image_lib_load(NULL);
  return rc != 0 ? rc : ts_lib->meta_set(meta, name, value);
}

int ts_meta_copy(const ts_meta *from, ts_meta **to) {
  int rc = ts_image_lib_load(NULL);
  return rc != 0 ? rc : ts_lib->meta_copy(from, to);
}
