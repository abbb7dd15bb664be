/* kill_at_rename.c - an LD_PRELOAD shim for fault tests: the process is
 * killed (SIGKILL) at the rename() that would publish a file.
 *
 * With TEXSYN_KILL_AT_RENAME=TEXT in the environment, the first rename()
 * whose destination path contains TEXT kills the process instead of
 * renaming: the file's bytes are written under their temporary name and
 * never published, as when a coordinator dies while writing a result. */
#include <dlfcn.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

int rename(const char *from, const char *to) {
  int (*real)(const char *, const char *) = (int (*)(const char *, const char *))dlsym(RTLD_NEXT, "rename");
  const char *at = getenv("TEXSYN_KILL_AT_RENAME");
  if (at != NULL && at[0] != '\0' && strstr(to, at) != NULL) raise(SIGKILL);
  return real(from, to);
}
