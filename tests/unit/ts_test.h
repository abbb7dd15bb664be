/* ts_test.h - shared main for cmocka unit-test binaries.
 *
 * Each test binary lists its tests with TS_TEST_MAIN(tests). Run with no
 * argument it runs them all; `--list` prints their names; a name runs just
 * that test. tests/run-unit.sh uses the last two to run every test in its own
 * process (libuv style), so one crash or leak cannot hide behind another. */
#ifndef TS_TEST_H
#define TS_TEST_H

#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <cmocka.h>

/* Directory of the shared test data (../shared/data from the repo root),
 * overridable with TEXSYN_DATA. */
static inline const char *ts_test_data_dir(void) {
  const char *d = getenv("TEXSYN_DATA");
  return d != NULL ? d : "../shared/data";
}

/* Writes n bytes to a new file under /tmp; its name into path. The test
 * unlinks it. */
static inline void ts_test_put_file(char path[32], const void *data, size_t n) {
  snprintf(path, 32, "/tmp/ts-test-XXXXXX");
  int fd = mkstemp(path);
  assert_true(fd >= 0);
  assert_int_equal(write(fd, data, n), (ssize_t)n);
  assert_int_equal(close(fd), 0);
}

/* Skips the running test and says why, on a line of its own ("skipped:
 * REASON") that tests/run-unit.sh puts on the test's SKIP line. A skip is
 * not a pass: `make test` allows it only where tests/skips.allow names
 * this test with this reason. */
#define ts_test_skip(...)  \
  do {                     \
    printf("skipped: ");   \
    printf(__VA_ARGS__);   \
    printf("\n");          \
    fflush(stdout);        \
    skip();                \
  } while (0)

#define TS_TEST_MAIN(group)                                                  \
  int main(int argc, char **argv) {                                          \
    size_t n_ = sizeof(group) / sizeof(group[0]);                            \
    if (argc > 1 && strcmp(argv[1], "--list") == 0) {                        \
      for (size_t i_ = 0; i_ < n_; i_++) printf("%s\n", group[i_].name);     \
      return 0;                                                              \
    }                                                                        \
    if (argc > 1) cmocka_set_test_filter(argv[1]);                           \
    return cmocka_run_group_tests_name(argv[0], group, NULL, NULL);          \
  }

#endif
