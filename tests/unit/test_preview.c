/* test_preview.c - the growing preview of a streamed result
 * (server/engines/preview.h): rows added top to bottom are box-averaged
 * into a picture of long side TS_PREVIEW_SIDE, written as a PNG at every
 * call; cells no row has reached are transparent; rows out of the image
 * are refused. */
#include "ts_test.h"

#include <stdlib.h>
#include <unistd.h>

#include "error.h"
#include "image.h"
#include "preview.h"

enum { W = 1024, H = 512 };

static void rows_grow_the_picture_top_to_bottom(void **state) {
  (void)state;
  char path[] = "/tmp/test_preview_XXXXXX.png", err[TS_ERR_LEN];
  int fd = mkstemps(path, 4);
  assert_true(fd >= 0);
  close(fd);
  ts_preview *p;
  assert_int_equal(ts_preview_open(&p, path, W, H, 3, err), 0);
  uint8_t *band = malloc((size_t)W * 64 * 3);
  /* Columns alternate 10 and 30 in red: each 4x4 cell averages 20. */
  for (int y = 0; y < 64; y++)
    for (int x = 0; x < W; x++) {
      uint8_t *o = band + ((size_t)y * W + (size_t)x) * 3;
      o[0] = x % 2 ? 30 : 10, o[1] = 200, o[2] = (uint8_t)(y < 32 ? 0 : 255);
    }
  assert_int_equal(ts_preview_rows(p, 0, 64, band, err), 0);
  ts_image img;
  assert_int_equal(ts_image_read(path, &img, NULL, err), 0);
  assert_int_equal(img.width, TS_PREVIEW_SIDE);
  assert_int_equal(img.height, TS_PREVIEW_SIDE / 2);
  assert_int_equal(img.channels, 4);
  const uint8_t *px = img.pixels;
  assert_int_equal(px[0], 20);
  assert_int_equal(px[1], 200);
  assert_int_equal(px[2], 0);
  assert_int_equal(px[3], 255);
  size_t row8 = (size_t)8 * TS_PREVIEW_SIDE * 4; /* preview row 8: image rows 32..35 */
  assert_int_equal(px[row8 + 2], 255);
  assert_int_equal(px[(size_t)16 * TS_PREVIEW_SIDE * 4 + 3], 0); /* image row 64: not yet */
  ts_image_free(&img);
  assert_int_not_equal(ts_preview_rows(p, H - 10, 64, band, err), 0);
  assert_non_null(strstr(err, "of an image of 512 rows"));
  free(band);
  ts_preview_close(p);
  unlink(path);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(rows_grow_the_picture_top_to_bottom),
};

int main(void) { return cmocka_run_group_tests(tests, NULL, NULL); }
