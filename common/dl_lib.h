/* dl_lib.h - finding and loading texsyn's own shared libraries.
 *
 * Code with heavy C++ dependencies lives in shared objects of its own,
 * dlopen'd on first use so that commands which never need it do not pay
 * for loading it: libtexsyn-image.so (OpenImageIO, image_lib.h) and
 * libtexsyn-flow.so (OpenCV, flow_lib.h). Each exports one symbol, a
 * versioned table of entry points; both are found the same way:
 *   1. $ENV, if set: that path only (tests and unusual installs; a wrong
 *      override must fail, not fall back to another library);
 *   2. next to the running executable (build/ in the source tree);
 *   3. ../lib/texsyn/ from the executable's directory, where `make install`
 *      puts it (PREFIX/bin/texsyn, PREFIX/lib/texsyn/LIB): relative, so an
 *      installed tree can move.
 * A candidate that is there but does not load ends the search with its
 * reason: a broken library must be seen, not skipped for another one.
 *
 * Loaded with RTLD_NOW, so that a library built against another version of
 * its dependencies fails here with a message rather than killing the
 * process at its first unbound call; RTLD_LOCAL keeps its symbols out of
 * the programs' namespace. Never unloaded: its functions may run on any
 * thread until exit, and C++ thread pools and statics do not unload
 * cleanly (leak checkers also need its symbols to stay mapped). */
#ifndef TS_DL_LIB_H
#define TS_DL_LIB_H

#include "error.h"

/* A library: what to look for (constant), then the outcome of the one
 * load, kept for the process's life. */
typedef struct {
  const char *file;  /* the file name, e.g. "libtexsyn-image.so" */
  const char *env;   /* the variable that overrides the search */
  const char *name;  /* the table's symbol */
  const char *what;  /* what messages call it, e.g. "image library" */
  int loaded, rc;    /* set by ts_dl_lib_load */
  const void *table; /* the table, once loaded */
  char err[TS_ERR_LEN];
} ts_dl_lib;

/* Finds and loads lib on the first call, then gives that outcome every
 * time: 0 with lib->table set, or TS_ENOTSUP with a message naming the
 * paths tried, the reason, and how to fix it. Thread-safe. */
int ts_dl_lib_load(ts_dl_lib *lib, char *err);

#endif
