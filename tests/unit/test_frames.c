/* test_frames.c - the frame numbers of `--frames A..B` sequences and the
 * patterns that put them in paths (server/cli/frames.c). */
#include <string.h>

#include "error.h"
#include "frames.h"
#include "ts_test.h"

static void frames_parse_takes_a_range(void **state) {
  (void)state;
  ts_frames f;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_frames_parse("1..10", &f, err), 0);
  assert_true(f.first == 1 && f.last == 10);
  assert_int_equal(ts_frames_parse("7..7", &f, err), 0);
  assert_true(f.first == 7 && f.last == 7);
  assert_int_equal(ts_frames_parse("0..9999", &f, err), 0);
  assert_int_equal(ts_frames_parse("999999..999999", &f, err), 0);
}

static void frames_parse_refuses_what_is_no_range(void **state) {
  (void)state;
  const char *bad[] = {"", "..", "1..", "..3", "1-3", "1...3", "a..b", "-1..3", "3..1", "0..10000", "1..1000000",
                       "1 ..3", "01234567890123456789012345678901234..2"};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    ts_frames f = {42, 42};
    char err[TS_ERR_LEN] = "";
    assert_int_equal(ts_frames_parse(bad[i], &f, err), TS_EINVAL);
    assert_non_null(strstr(err, "--frames"));
  }
}

static void frame_pattern_counts_frame_numbers_only(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_frame_pattern("out.png", err), 0);
  assert_int_equal(ts_frame_pattern("out_%04d.png", err), 1);
  assert_int_equal(ts_frame_pattern("%d/out_%d.png", err), 2);
  assert_int_equal(ts_frame_pattern("100%%_%3d.png", err), 1);
  assert_int_equal(ts_frame_pattern("100%%.png", err), 0);
  const char *bad[] = {"out_%s.png", "out_%x.png", "%", "out_%-4d.png", "out_%04.png", "out_%0123456789d.png"};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) assert_int_equal(ts_frame_pattern(bad[i], err), TS_EINVAL);
}

static void frame_path_puts_the_number_in(void **state) {
  (void)state;
  char out[64];
  assert_int_equal(ts_frame_path("out_%04d.png", 7, out, sizeof(out)), 0);
  assert_string_equal(out, "out_0007.png");
  assert_int_equal(ts_frame_path("f%d_%3d.%%.png", 12345, out, sizeof(out)), 0);
  assert_string_equal(out, "f12345_12345.%.png");
  assert_int_equal(ts_frame_path("a%5db", 42, out, sizeof(out)), 0);
  assert_string_equal(out, "a   42b");
  assert_int_equal(ts_frame_path("plain.png", 3, out, sizeof(out)), 0);
  assert_string_equal(out, "plain.png");
}

static void frame_path_refuses_what_does_not_fit(void **state) {
  (void)state;
  char out[12];
  assert_int_equal(ts_frame_path("out_%04d.png", 1, out, sizeof(out)), TS_ETOOBIG); /* 12 bytes and the NUL */
  assert_int_equal(ts_frame_path("out_%04d.pn", 1, out, sizeof(out)), 0);
  assert_string_equal(out, "out_0001.pn");
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(frames_parse_takes_a_range),
    cmocka_unit_test(frames_parse_refuses_what_is_no_range),
    cmocka_unit_test(frame_pattern_counts_frame_numbers_only),
    cmocka_unit_test(frame_path_puts_the_number_in),
    cmocka_unit_test(frame_path_refuses_what_does_not_fit),
};

TS_TEST_MAIN(tests)
