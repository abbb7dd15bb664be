/* util.h - small helpers every layer uses: the monotonic clock, whole-file
 * reads, numeric option parsing. One copy each, here. */
#ifndef TS_UTIL_H
#define TS_UTIL_H

#include <stdint.h>

/* Seconds on the monotonic clock (for durations and deadlines only). */
double ts_now(void);

#endif
