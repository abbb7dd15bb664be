/* stop.h - how a daemon stops on SIGTERM or SIGINT.
 *
 * The kernel hands a process-directed signal to any thread that does not
 * block it: a scan or connection thread as often as the main thread waiting
 * in accept(). Setting a flag alone then leaves accept() asleep until the
 * next peer connects, and a `kill` is ignored (the hostile test caught a
 * worker doing so). So the handler also shuts the listening socket down:
 * accept() returns at once in whichever thread waits there, and fails at
 * once on any later call, so there is no window between the flag's check
 * and the call. */
#ifndef TS_STOP_H
#define TS_STOP_H

#include <stdatomic.h>

/* Installs the handler for SIGTERM and SIGINT (without SA_RESTART): it
 * sets *flag to 1 and shuts down the socket given to ts_stop_listener. */
void ts_stop_on_signals(atomic_int *flag);

/* The listening socket a stop shuts down (-1: none). */
void ts_stop_listener(int fd);

#endif
