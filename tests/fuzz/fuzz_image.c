/* fuzz_image.c - libFuzzer target for the image-loading path: the input is
 * a reference file's bytes, read by ts_image_read_mem, the code path of
 * ts_image_read (format sniffing, OpenImageIO's PNG, JPEG, TIFF and
 * OpenEXR readers, the header checks and limits, the GeoTIFF tag reader)
 * on bytes instead of a file. The probe the coordinator runs at submit
 * must agree with the read. Any crash, sanitizer report, leak, or an error
 * without a one-line message naming the input is a bug.
 *
 * The pixel limit is 256 Kpixels rather than the default 256 M: a header under
 * the limit makes OpenImageIO's decoders allocate (and zero) the claimed
 * size, which at 256 Mpixels alone passes libFuzzer's 2 GB RSS limit (that
 * is what --max-pixels is for, not a bug to find again and again) and at
 * 4 Mpixels still slows the run to a few inputs a second. The limit check
 * itself is the same code at any value.
 * OpenImageIO and the codec libraries are not instrumented, so coverage
 * guides the fuzzer through our code only: the shim, in an image library
 * built with the fuzzer's flags (build-fuzz/libtexsyn-image.so), and the
 * checks before it. Build and run: make fuzz. */
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "image.h"

int LLVMFuzzerInitialize(int *argc, char ***argv);
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* The image library is loaded before the first input: its coverage
 * counters are then registered with the fuzzer's other modules at start,
 * and a library that does not load stops the run with its reason instead
 * of failing every input's message check. */
int LLVMFuzzerInitialize(int *argc, char ***argv) {
  (void)argc;
  (void)argv;
  char err[TS_ERR_LEN];
  if (ts_image_lib_load(err) != 0) {
    fprintf(stderr, "fuzz_image: %s\n", err);
    exit(1);
  }
  return 0;
}

#define FUZZ_MAX_PIXELS (256u << 10)
static const char kName[] = "fuzz-input.img";

static void check_message(const char *err) {
  if (memchr(err, '\0', TS_ERR_LEN) == NULL || strstr(err, kName) == NULL || strchr(err, '\n'))
    abort();
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  ts_image_limits limits = {FUZZ_MAX_PIXELS, "--max-pixels"};
  char err[TS_ERR_LEN] = "";
  ts_image_info info;
  int probed = ts_image_probe_mem(kName, data, size, &limits, &info, err);
  if (probed != 0) check_message(err);

  ts_image img;
  err[0] = '\0';
  int rc = ts_image_read_mem(kName, data, size, &img, &limits, err);
  if (rc != 0) {
    check_message(err);
    if (img.pixels != NULL) abort();
    /* The probe may pass a file cut inside its pixels, never the reverse
     * of a read; a failed probe fails the read the same way. */
    if (probed != 0 && rc != probed) abort();
    return 0;
  }
  if (probed != 0) abort(); /* read what the probe refused */
  if (img.pixels == NULL || img.width != info.width || img.height != info.height ||
      img.channels != info.channels || img.type != info.type)
    abort();
  if ((uint64_t)img.width * (uint64_t)img.height > FUZZ_MAX_PIXELS || img.channels < 1 ||
      img.channels > 16)
    abort();
  /* Every sample converts (NaN, infinities, subnormal halves). */
  size_t n = (size_t)img.width * (size_t)img.height;
  uint8_t *luma = malloc(n);
  if (luma != NULL) {
    ts_image_luma8(&img, luma);
    free(luma);
  }
  ts_image_free(&img);
  return 0;
}
