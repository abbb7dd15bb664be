/* fuzz_jobspec.c - libFuzzer target for the job-spec text parser
 * (server/engines/jobspec.c), the text a client submits and the spool keeps. The
 * input is the spec, not NUL-terminated. A spec the parser accepts must
 * format back and parse again to the same spec (what a restarted
 * coordinator reads from job.spec); any crash, sanitizer report or failed
 * round trip is a bug. Build and run: make fuzz. */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "jobspec.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  char err[TS_ERR_LEN];
  ts_jobspec s;
  /* An exact-size copy, so reading one byte past the input is caught. */
  char *text = malloc(size ? size : 1);
  if (text == NULL) return 0;
  if (size) memcpy(text, data, size);
  int rc = ts_jobspec_parse(text, size, &s, err);
  free(text);
  if (rc != 0) {
    if (memchr(err, '\0', TS_ERR_LEN) == NULL || err[0] == '\0') abort(); /* no message */
    return 0;
  }
  char buf[4096];
  int n = ts_jobspec_format(&s, buf, sizeof(buf));
  if (n < 0) abort(); /* an accepted spec must fit what a client may send */
  ts_jobspec back;
  if (ts_jobspec_parse(buf, (size_t)n, &back, err) != 0) abort();
  char again[4096];
  int m = ts_jobspec_format(&back, again, sizeof(again));
  if (m != n || memcmp(buf, again, (size_t)n) != 0) abort();
  return 0;
}
