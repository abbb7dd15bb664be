/* test_util.c - the shared helpers: numeric parsers and the whole-file
 * reader (util.c), the daemons' log (log.c). */
#include <limits.h>
#include <stdio.h>
#include <unistd.h>

#include "error.h"
#include "log.h"
#include "ts_test.h"
#include "util.h"

/* --- all parsers -------------------------------------------------------------- */

static void parsers_refuse_garbage_and_empty(void **state) {
  (void)state;
  const char *bad[] = {"", " ", "abc", "12abc", "12 ", "1,5", "--3", "0x1y"};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    long l = 99;
    uint64_t u = 99;
    double d = 99;
    int w = 99, h = 99;
    assert_int_equal(ts_parse_long(bad[i], LONG_MIN, LONG_MAX, &l), TS_EINVAL);
    assert_int_equal(ts_parse_u64(bad[i], &u), TS_EINVAL);
    assert_int_equal(ts_parse_double(bad[i], &d), TS_EINVAL);
    assert_int_not_equal(ts_parse_size(bad[i], 1000000, &w, &h), 0);
    assert_true(l == 99 && u == 99 && d == 99 && w == 99 && h == 99); /* left alone */
  }
}

/* --- ts_parse_long / ts_parse_int ----------------------------------------- */

static void parse_long_takes_decimal_only(void **state) {
  (void)state;
  long v;
  assert_int_equal(ts_parse_long("1.5", 0, 10, &v), TS_EINVAL);
  assert_int_equal(ts_parse_long("0x10", 0, 100, &v), TS_EINVAL);
  assert_int_equal(ts_parse_long("1e3", 0, 10000, &v), TS_EINVAL);
  assert_int_equal(ts_parse_long("010", 0, 100, &v), 0); /* not octal */
  assert_int_equal(v, 10);
}


static void parse_long_takes_whole_numbers_in_range(void **state) {
  (void)state;
  long v;
  assert_int_equal(ts_parse_long("42", 0, 100, &v), 0);
  assert_int_equal(v, 42);
  assert_int_equal(ts_parse_long("-7", -10, 10, &v), 0);
  assert_int_equal(v, -7);
  assert_int_equal(ts_parse_long("+5", 0, 10, &v), 0); /* as strtol takes them */
  assert_int_equal(v, 5);
  assert_int_equal(ts_parse_long(" 8", 0, 10, &v), 0);
  assert_int_equal(v, 8);
}

static void parse_long_bounds_are_inclusive(void **state) {
  (void)state;
  long v;
  assert_int_equal(ts_parse_long("1", 1, 1024, &v), 0);
  assert_int_equal(ts_parse_long("1024", 1, 1024, &v), 0);
  assert_int_equal(v, 1024);
  assert_int_equal(ts_parse_long("0", 1, 1024, &v), TS_EINVAL);
  assert_int_equal(ts_parse_long("1025", 1, 1024, &v), TS_EINVAL);
}

static void parse_long_refuses_overflow(void **state) {
  (void)state;
  long v;
  assert_int_equal(ts_parse_long("99999999999999999999999", LONG_MIN, LONG_MAX, &v), TS_EINVAL);
  assert_int_equal(ts_parse_long("-99999999999999999999999", LONG_MIN, LONG_MAX, &v), TS_EINVAL);
}

static void parse_int_takes_the_int_range(void **state) {
  (void)state;
  int v;
  assert_int_equal(ts_parse_int("2147483647", INT_MIN, INT_MAX, &v), 0);
  assert_int_equal(v, INT_MAX);
  assert_int_equal(ts_parse_int("-2147483648", INT_MIN, INT_MAX, &v), 0);
  assert_int_equal(v, INT_MIN);
  assert_int_equal(ts_parse_int("2147483648", INT_MIN, INT_MAX, &v), TS_EINVAL);
  assert_int_equal(ts_parse_int("2", 0, 1, &v), TS_EINVAL);
}

/* --- ts_parse_u64 ------------------------------------------------------------ */

static void parse_u64_takes_the_full_range(void **state) {
  (void)state;
  uint64_t v;
  assert_int_equal(ts_parse_u64("0", &v), 0);
  assert_true(v == 0);
  assert_int_equal(ts_parse_u64("18446744073709551615", &v), 0);
  assert_true(v == UINT64_MAX);
}

static void parse_u64_refuses_overflow_and_fractions(void **state) {
  (void)state;
  uint64_t v;
  assert_int_equal(ts_parse_u64("18446744073709551616", &v), TS_EINVAL);
  assert_int_equal(ts_parse_u64("1.0", &v), TS_EINVAL);
}

static void parse_u64_refuses_a_sign(void **state) {
  (void)state;
  uint64_t v = 7;
  assert_int_equal(ts_parse_u64("-1", &v), TS_EINVAL); /* not 2^64-1 */
  assert_int_equal(ts_parse_u64(" -1", &v), TS_EINVAL);
  assert_int_equal(ts_parse_u64("-0", &v), TS_EINVAL);
  assert_true(v == 7);
}

/* --- ts_parse_double --------------------------------------------------------- */

static void parse_double_takes_numbers(void **state) {
  (void)state;
  double v;
  assert_int_equal(ts_parse_double("0.5", &v), 0);
  assert_true(v == 0.5);
  assert_int_equal(ts_parse_double("-2", &v), 0);
  assert_true(v == -2.0);
  assert_int_equal(ts_parse_double("1e-3", &v), 0);
  assert_true(v == 1e-3);
}

static void parse_double_refuses_non_finite_and_out_of_range(void **state) {
  (void)state;
  const char *bad[] = {"inf", "-inf", "nan", "1e400", "1e-400"};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    double v = 3.0;
    assert_int_equal(ts_parse_double(bad[i], &v), TS_EINVAL);
    assert_true(v == 3.0);
  }
}

/* --- ts_parse_size ----------------------------------------------------------- */

static void parse_size_takes_w_x_h(void **state) {
  (void)state;
  int w = 0, h = 0;
  assert_int_equal(ts_parse_size("64x32", 1000000, &w, &h), 0);
  assert_int_equal(w, 64);
  assert_int_equal(h, 32);
  assert_int_equal(ts_parse_size("7X9", 1000000, &w, &h), 0);
  assert_int_equal(w * 100 + h, 709);
  assert_int_equal(ts_parse_size("1x1000000", 1000000, &w, &h), 0);
  assert_int_equal(h, 1000000);
}

static void parse_size_tells_what_is_not_a_size(void **state) {
  (void)state;
  const char *bad[] = {"", "64", "64by64", "x64", "abcx5", "64 x 64"};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    int w = -1, h = -1;
    assert_int_equal(ts_parse_size(bad[i], 1000000, &w, &h), TS_EFORMAT);
    assert_int_equal(w, -1);
    assert_int_equal(h, -1);
  }
}

static void parse_size_refuses_numbers_out_of_range(void **state) {
  (void)state;
  const char *bad[] = {"0x5",  "5x0",      "1000001x5", "5x1000001", "-5x5",
                       "64x",  "64xabc",   "64x64x64",  "99999999999999999999x5"};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    int w = -1, h = -1;
    assert_int_equal(ts_parse_size(bad[i], 1000000, &w, &h), TS_EINVAL);
    assert_int_equal(w, -1);
  }
}

/* --- ts_file_read ---------------------------------------------------------------- */

/* ts_file_read on a temporary file of n bytes of data, at most max; the
 * file's name into path (removed by then), the message into err. */
static int read_temp(const void *data, size_t n, size_t max, uint8_t **buf, size_t *len,
                     char err[TS_ERR_LEN], char path[32]) {
  ts_test_put_file(path, data, n);
  int rc = ts_file_read(path, max, buf, len, err);
  unlink(path);
  return rc;
}

static void file_read_gives_the_exact_content(void **state) {
  (void)state;
  static const uint8_t bytes[] = {'a', 0, 0xff, '\n', 'z'};
  uint8_t *buf;
  size_t len;
  char err[TS_ERR_LEN], path[32];
  assert_int_equal(read_temp(bytes, sizeof(bytes), 1 << 20, &buf, &len, err, path), 0);
  assert_int_equal(len, sizeof(bytes));
  assert_memory_equal(buf, bytes, sizeof(bytes));
  assert_int_equal(buf[len], '\0'); /* usable as a string */
  free(buf);
}

static void file_read_takes_an_empty_file(void **state) {
  (void)state;
  uint8_t *buf;
  size_t len = 99;
  char err[TS_ERR_LEN], path[32];
  assert_int_equal(read_temp("", 0, 0, &buf, &len, err, path), 0);
  assert_int_equal(len, 0);
  assert_int_equal(buf[0], '\0');
  free(buf);
}

static void file_read_names_a_missing_file(void **state) {
  (void)state;
  const char *path = "/nonexistent/nope.png";
  uint8_t *buf = (uint8_t *)"x";
  size_t len;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_file_read(path, 1 << 20, &buf, &len, err), TS_EIO);
  assert_null(buf);
  assert_non_null(strstr(err, path));
  assert_non_null(strstr(err, "No such file"));
}

static void file_read_refuses_a_file_over_the_limit(void **state) {
  (void)state;
  uint8_t *buf;
  size_t len;
  char err[TS_ERR_LEN], path[32];
  assert_int_equal(read_temp("0123456789", 10, 9, &buf, &len, err, path), TS_ETOOBIG);
  assert_null(buf);
  assert_int_equal(len, 10); /* the size, for the caller's message */
  assert_non_null(strstr(err, path));
  assert_non_null(strstr(err, "limit of 9"));
}

static void file_read_takes_a_file_at_the_limit(void **state) {
  (void)state;
  uint8_t *buf;
  size_t len;
  char err[TS_ERR_LEN], path[32];
  assert_int_equal(read_temp("0123456789", 10, 10, &buf, &len, err, path), 0);
  assert_int_equal(len, 10);
  free(buf);
}

static void file_read_refuses_a_directory(void **state) {
  (void)state;
  const char *dir = "/tmp";
  uint8_t *buf;
  size_t len;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_file_read(dir, 1 << 20, &buf, &len, err), TS_EIO);
  assert_null(buf);
  assert_non_null(strstr(err, dir));
  assert_non_null(strstr(err, "not a regular file"));
}

/* --- ts_file_write / ts_file_create / ts_file_commit ------------------------- */

/* The file at path whole, as a string (one at a time). */
static const char *whole(const char *path) {
  static char text[256];
  uint8_t *buf;
  size_t len;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_file_read(path, sizeof(text) - 1, &buf, &len, err), 0);
  memcpy(text, buf, len + 1);
  free(buf);
  return text;
}

static void file_write_replaces_the_file_whole(void **state) {
  (void)state;
  char path[] = "/tmp/ts-test-write-XXXXXX", err[TS_ERR_LEN];
  close(mkstemp(path));
  assert_int_equal(ts_file_write(path, "old", 3, err), 0);
  assert_int_equal(ts_file_write(path, "new content", 11, err), 0);
  assert_string_equal(whole(path), "new content");
  assert_int_equal(ts_file_write(path, "", 0, err), 0);
  assert_string_equal(whole(path), "");
  unlink(path);
}

static void file_commit_not_ok_keeps_the_old_file_and_no_temporary(void **state) {
  (void)state;
  char path[] = "/tmp/ts-test-commit-XXXXXX", tmp[TS_FILE_TMP_LEN], err[TS_ERR_LEN] = "";
  close(mkstemp(path));
  assert_int_equal(ts_file_write(path, "kept", 4, err), 0);
  FILE *f = ts_file_create(path, tmp, err);
  assert_non_null(f);
  fputs("half of it", f);
  assert_int_equal(ts_file_commit(f, tmp, path, 0, err), TS_EIO);
  assert_non_null(strstr(err, path));
  assert_string_equal(whole(path), "kept");
  assert_int_not_equal(access(tmp, F_OK), 0);
  unlink(path);
}

static void file_create_names_a_path_it_cannot_write(void **state) {
  (void)state;
  char tmp[TS_FILE_TMP_LEN], err[TS_ERR_LEN] = "";
  const char *path = "/nonexistent-dir/out.json";
  assert_null(ts_file_create(path, tmp, err));
  assert_non_null(strstr(err, path));
  assert_int_equal(ts_file_write(path, "x", 1, err), TS_EIO);
}

/* --- ts_log ---------------------------------------------------------------------- */

/* What the log wrote to f, from the start. */
static char *log_text(FILE *f) {
  static char text[4096];
  rewind(f);
  size_t n = fread(text, 1, sizeof(text) - 1, f);
  text[n] = '\0';
  return text;
}

static void log_line_has_the_prefix_and_utc_time(void **state) {
  (void)state;
  FILE *f = tmpfile();
  assert_non_null(f);
  ts_log_init("texsyn-test", f, 0);
  ts_log("job %d queued", 5);
  char *text = log_text(f);
  int y, mo, d, h, mi, s, n = 0;
  assert_int_equal(sscanf(text, "texsyn-test: %4d-%2d-%2dT%2d:%2d:%2dZ %n", &y, &mo, &d, &h, &mi, &s, &n), 6);
  assert_string_equal(text + n, "job 5 queued\n");
  assert_int_equal(text[n - 2], 'Z');
  fclose(f);
}

static void log_escapes_control_bytes(void **state) {
  (void)state;
  FILE *f = tmpfile();
  assert_non_null(f);
  ts_log_init("t", f, 0);
  ts_log("worker joining (%s)", "x\ntexsyn-server: forged\x1b[2J\x7f\t\xc3\xa9");
  char *text = log_text(f);
  char *at = strstr(text, "Z worker joining (");
  assert_non_null(at);
  assert_string_equal(at, "Z worker joining (x\\x0atexsyn-server: forged\\x1b[2J\\x7f\\x09\xc3\xa9)\n");
  fclose(f);
}

static void log_limited_writes_one_line_and_holds_the_rest(void **state) {
  (void)state;
  FILE *f = tmpfile();
  assert_non_null(f);
  ts_log_init("t", f, 1); /* written even when quiet */
  ts_log_limit l = TS_LOG_LIMIT_INIT;
  for (int i = 0; i < 5; i++) ts_log_limited(&l, "closed peer %d", i);
  char *text = log_text(f);
  assert_non_null(strstr(text, "Z closed peer 0\n"));
  assert_null(strstr(text, "peer 1"));
  assert_int_equal(l.held, 4);
  fclose(f);
}

static void parse_bytes_takes_binary_suffixes(void **state) {
  (void)state;
  uint64_t v = 1;
  assert_int_equal(ts_parse_bytes("0", &v), 0);
  assert_int_equal(v, 0);
  assert_int_equal(ts_parse_bytes("512", &v), 0);
  assert_int_equal(v, 512);
  assert_int_equal(ts_parse_bytes("64K", &v), 0);
  assert_int_equal(v, 65536);
  assert_int_equal(ts_parse_bytes("1.5G", &v), 0);
  assert_int_equal(v, 3ull << 29);
  assert_int_equal(ts_parse_bytes("2T", &v), 0);
  assert_int_equal(v, 2ull << 40);
  const char *bad[] = {"", "M", "1X", "1MB", "-1", "1e30", "nan"};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    v = 7;
    assert_int_equal(ts_parse_bytes(bad[i], &v), TS_EINVAL);
    assert_int_equal(v, 7);
  }
}

static void log_quiet_drops_events_not_warnings(void **state) {
  (void)state;
  FILE *f = tmpfile();
  assert_non_null(f);
  ts_log_init("w", f, 1);
  ts_log("an event");
  ts_warn("refused %s", "peer");
  ts_warn_msg("coil write refused");
  char *text = log_text(f);
  assert_null(strstr(text, "an event"));
  char *first = strstr(text, "Z refused peer\n");
  assert_non_null(first);
  assert_non_null(strstr(first, "Z coil write refused\n"));
  fclose(f);
}

/* A wait's deadline lies the given time ahead on the realtime clock,
 * with a normalised nanosecond field. */
static void wait_until_is_that_far_ahead(void **state) {
  (void)state;
  double ahead[] = {0.0, 0.5, 0.999999999, 2.25};
  for (int k = 0; k < 4; k++) {
    struct timespec at = ts_wait_until(ahead[k]), later;
    clock_gettime(CLOCK_REALTIME, &later);
    double t = (double)at.tv_sec + at.tv_nsec * 1e-9, now = (double)later.tv_sec + later.tv_nsec * 1e-9;
    assert_true(at.tv_nsec >= 0 && at.tv_nsec < 1000000000L);
    assert_true(t <= now + ahead[k] + 1e-6);
    assert_true(t > now + ahead[k] - 1.0); /* the call took well under a second */
  }
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(wait_until_is_that_far_ahead),
    cmocka_unit_test(parsers_refuse_garbage_and_empty),
    cmocka_unit_test(parse_long_takes_whole_numbers_in_range),
    cmocka_unit_test(parse_long_takes_decimal_only),
    cmocka_unit_test(parse_long_bounds_are_inclusive),
    cmocka_unit_test(parse_long_refuses_overflow),
    cmocka_unit_test(parse_int_takes_the_int_range),
    cmocka_unit_test(parse_u64_takes_the_full_range),
    cmocka_unit_test(parse_u64_refuses_overflow_and_fractions),
    cmocka_unit_test(parse_u64_refuses_a_sign),
    cmocka_unit_test(parse_double_takes_numbers),
    cmocka_unit_test(parse_double_refuses_non_finite_and_out_of_range),
    cmocka_unit_test(parse_size_takes_w_x_h),
    cmocka_unit_test(parse_size_tells_what_is_not_a_size),
    cmocka_unit_test(parse_size_refuses_numbers_out_of_range),
    cmocka_unit_test(file_read_gives_the_exact_content),
    cmocka_unit_test(file_read_takes_an_empty_file),
    cmocka_unit_test(file_read_names_a_missing_file),
    cmocka_unit_test(file_read_refuses_a_file_over_the_limit),
    cmocka_unit_test(file_read_takes_a_file_at_the_limit),
    cmocka_unit_test(file_read_refuses_a_directory),
    cmocka_unit_test(file_write_replaces_the_file_whole),
    cmocka_unit_test(file_commit_not_ok_keeps_the_old_file_and_no_temporary),
    cmocka_unit_test(file_create_names_a_path_it_cannot_write),
    cmocka_unit_test(log_line_has_the_prefix_and_utc_time),
    cmocka_unit_test(log_quiet_drops_events_not_warnings),
    cmocka_unit_test(log_escapes_control_bytes),
    cmocka_unit_test(parse_bytes_takes_binary_suffixes),
    cmocka_unit_test(log_limited_writes_one_line_and_holds_the_rest),
};

TS_TEST_MAIN(tests)
