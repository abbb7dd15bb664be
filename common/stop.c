/* stop.c - stopping a daemon on a signal, whichever thread receives it
 * (see stop.h for why the listening socket is shut down). */
#include "stop.h"

#include <errno.h>
#include <signal.h>
#include <string.h>
#include <sys/socket.h>

static atomic_int *g_flag;
static atomic_int g_listener = -1;

/* Only async-signal-safe calls: an atomic store and shutdown(2). */
static void on_stop_signal(int sig) {
  (void)sig;
  int saved = errno;
  if (g_flag != NULL) atomic_store(g_flag, 1);
  int fd = atomic_load(&g_listener);
  if (fd >= 0) shutdown(fd, SHUT_RDWR);
  errno = saved;
}

void ts_stop_on_signals(atomic_int *flag) {
  g_flag = flag;
  struct sigaction sa;
  memset(&sa, 0, sizeof(sa));
  sa.sa_handler = on_stop_signal;
  sigemptyset(&sa.sa_mask);
  sigaction(SIGTERM, &sa, NULL);
  sigaction(SIGINT, &sa, NULL);
}

void ts_stop_listener(int fd) {
  atomic_store(&g_listener, fd);
  /* A signal that came before the socket existed: stop it now too. */
  if (fd >= 0 && g_flag != NULL && atomic_load(g_flag)) shutdown(fd, SHUT_RDWR);
}
