/* error.c - see error.h. */
#include "error.h"

#include <stdarg.h>
#include <stdio.h>

const char *ts_strerror(int code) {
  switch (code) {
  case TS_OK:
    return "success";
#define TS_ERR_TEXT(name, val, text) \
  case TS_##name:                    \
    return text;
    TS_ERRNO_MAP(TS_ERR_TEXT)
#undef TS_ERR_TEXT
  default:
    return "unknown error";
  }
}

int ts_error(char *err, int code, const char *fmt, ...) {
  if (err != NULL) {
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(err, TS_ERR_LEN, fmt, ap);
    va_end(ap);
  }
  return code;
}
