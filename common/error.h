/* error.h - error codes and messages shared by every texsyn module.
 *
 * Like libuv, every fallible function returns 0 on success or a negative
 * TS_E* code; it never aborts on bad input. Functions that can explain
 * themselves also take a caller-owned `char *err` buffer of TS_ERR_LEN bytes
 * and write one line a user can act on (naming the file, option or value at
 * fault). The same codes travel on the wire in later protocol messages, so
 * their numeric values are part of the protocol and must never change. */
#ifndef TS_ERROR_H
#define TS_ERROR_H

#include <stddef.h>

#define TS_ERR_LEN 512

/* X-macro table: name, value, text. */
#define TS_ERRNO_MAP(XX)                                              \
  XX(EINVAL, -1, "invalid argument")                                  \
  XX(ENOMEM, -2, "out of memory")                                     \
  XX(EIO, -3, "input/output error")                                   \
  XX(EFORMAT, -4, "unsupported or corrupt file format")               \
  XX(ETOOBIG, -5, "size limit exceeded")                              \
  XX(ENOTSUP, -6, "not supported on this machine")                    \
  XX(EPROTO, -7, "protocol error")                                    \
  XX(ECANCELED, -8, "operation canceled")                             \
  XX(ENOENT, -9, "no such file or object")                            \
  XX(EAUTH, -10, "authentication failed")                             \
  XX(ETIMEDOUT, -11, "timed out")                                     \
  XX(ECONN, -12, "connection failed")                                 \
  XX(ELIMIT, -13, "limit reached")                                    \
  XX(ESTALE, -14, "the state changed meanwhile: try again")           \
  XX(ESTOPPED, -15, "stopped at a checkpoint, to resume later")

enum {
#define TS_ERR_ENUM(name, val, text) TS_##name = (val),
  TS_ERRNO_MAP(TS_ERR_ENUM)
#undef TS_ERR_ENUM
  TS_OK = 0
};

/* Text for a TS_E* code ("unknown error" for anything else). */
const char *ts_strerror(int code);

/* Formats a message into err (if err is not NULL) and returns code, so an
 * error path is one line: `return ts_error(err, TS_EINVAL, "...", ...);` */
int ts_error(char *err, int code, const char *fmt, ...)
    __attribute__((format(printf, 3, 4)));

#endif
