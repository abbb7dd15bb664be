/* fail_poll.c - an LD_PRELOAD shim for fault tests: poll() fails once.
 *
 * With TEXSYN_FAIL_POLL_AT=N in the environment, the N-th call of the
 * process that waits on at least two descriptors with a finite timeout
 * returns -1 with errno ENOMEM instead of polling. In texsyn-server only the
 * exchanges with two or more workers poll like that (single connections
 * poll one descriptor, the Modbus plane waits without a timeout), so the
 * failure lands inside an exchange, where it must never pass for an
 * answer. */
#include <dlfcn.h>
#include <errno.h>
#include <poll.h>
#include <stdatomic.h>
#include <stdlib.h>

int poll(struct pollfd *fds, nfds_t nfds, int timeout) {
  static atomic_long calls;
  int (*real)(struct pollfd *, nfds_t, int) = (int (*)(struct pollfd *, nfds_t, int))dlsym(RTLD_NEXT, "poll");
  const char *at = getenv("TEXSYN_FAIL_POLL_AT");
  if (at != NULL && nfds >= 2 && timeout >= 0 && atomic_fetch_add(&calls, 1) + 1 == atol(at)) {
    errno = ENOMEM;
    return -1;
  }
  return real(fds, nfds, timeout);
}
