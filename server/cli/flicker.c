/* flicker.c - `texsyn flicker`: the temporal coherence of a stylized
 * sequence, the measure of issue 27 (video stylization) and of Jamriška et
 * al. 2019's comparisons.
 *
 * For each step t-1 -> t: the flows between input frames t and t-1, both
 * ways, on their luminance (the stylized frames are what is judged, so
 * they cannot be what motion is measured on); stylized frame t-1 warped
 * onto frame t along the backward flow; the mean absolute difference to
 * stylized frame t over the pixels the forward-backward check keeps (the
 * occluded ones have no counterpart in t-1, so any value there is right).
 * A sequence that follows its input's motion scores near 0 whatever its
 * style; one painted anew each frame scores high.
 *
 * Every frame is checked first (there, readable, one size): a missing or
 * odd frame fails before any flow is computed. Then two frames are held at
 * a time; the flows are computed one after another in this thread, as
 * libtexsyn-flow.so's determinism asks (flow_cv.cpp). */
#include "flicker.h"

#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "flow.h"
#include "frames.h"
#include "image.h"
#include "util.h"

static const char *const kUsage =
    "usage: texsyn flicker --frames A..B --input PATTERN --image PATTERN [--json]\n"
    "\n"
    "Scores the temporal coherence of a stylized sequence: for each step from frame\n"
    "t-1 to t, stylized frame t-1 is warped onto frame t along the optical flow of\n"
    "the input frames (OpenCV's DIS, computed on their luminance, both ways), and\n"
    "compared with stylized frame t; pixels the forward-backward check finds\n"
    "occluded are left out. Prints the mean over the steps of the mean absolute\n"
    "difference (per channel, 8-bit units: 0 is perfectly coherent), the worst step\n"
    "and the share of pixels left out.\n"
    "\n"
    "  --frames A..B     the frame numbers, at least two\n"
    "  --input PATTERN   the input frames, the frame number as %d or %04d\n"
    "                    (e.g. shot/%04d.png); at least 32x32\n"
    "  --image PATTERN   the stylized frames, the inputs' size\n"
    "  --json            one JSON object instead, with every step's score\n";

#define FLICKER_PATH 4096
#define FLICKER_MAX_FILE (1ull << 32) /* bytes of one frame's file */

typedef struct {
  const char *input, *image;
  ts_frames fr;
  int json;
} flicker_opts;

/* One sequence (--input or --image): what the checks found. */
typedef struct {
  const char *option, *pattern;
  ts_image_info first;
} sequence;

typedef struct {
  double error;    /* mean absolute difference over the kept pixels and channels */
  double occluded; /* share of frame t's pixels left out */
} step_score;

enum { OPT_FRAMES = 256, OPT_INPUT, OPT_IMAGE, OPT_JSON, OPT_HELP };

static int parse(int argc, char **argv, flicker_opts *o, char *err) {
  static const struct option opts[] = {
      {"frames", required_argument, 0, OPT_FRAMES}, {"input", required_argument, 0, OPT_INPUT},
      {"image", required_argument, 0, OPT_IMAGE},   {"json", no_argument, 0, OPT_JSON},
      {"help", no_argument, 0, OPT_HELP},           {0, 0, 0, 0}};
  const char *frames = NULL;
  optind = 1;
  opterr = 0;
  int c, rc = 0;
  while (rc == 0 && (c = getopt_long(argc, argv, "h", opts, NULL)) != -1) {
    switch (c) {
    case OPT_FRAMES: frames = optarg; break;
    case OPT_INPUT: o->input = optarg; break;
    case OPT_IMAGE: o->image = optarg; break;
    case OPT_JSON: o->json = 1; break;
    case OPT_HELP: case 'h': printf("%s", kUsage); exit(0);
    default: return ts_error(err, TS_EINVAL, "unknown option or missing value\n%s", kUsage);
    }
  }
  if (optind < argc) return ts_error(err, TS_EINVAL, "unexpected argument '%s'\n%s", argv[optind], kUsage);
  if (frames == NULL || o->input == NULL || o->image == NULL)
    return ts_error(err, TS_EINVAL, "--frames, --input and --image are required\n%s", kUsage);
  rc = ts_frames_parse(frames, &o->fr, err);
  if (rc == 0 && o->fr.first == o->fr.last)
    rc = ts_error(err, TS_EINVAL, "--frames %s: one frame has no step to score; give at least two", frames);
  return rc;
}

/* err, a message about frame f of option (or of the sequence), says so. */
static int in_frame(char *err, int rc, const char *option, long f, const char *tail) {
  char why[TS_ERR_LEN];
  snprintf(why, sizeof(why), "%s", err);
  return ts_error(err, rc, "%s%sframe %ld: %s%s", option ? option : "", option ? " " : "", f, why, tail);
}

/* The header of frame f of s, its path into path. */
static int probe_frame(const sequence *s, long f, char *path, ts_image_info *info, char *err) {
  if (ts_frame_path(s->pattern, f, path, FLICKER_PATH) != 0)
    return ts_error(err, TS_ETOOBIG, "%s %s: the path of frame %ld is too long", s->option, s->pattern, f);
  uint8_t *buf = NULL;
  size_t len = 0;
  int rc = ts_file_read(path, FLICKER_MAX_FILE, &buf, &len, err);
  if (rc == 0) rc = ts_image_probe_mem(path, buf, len, NULL, info, err);
  free(buf);
  return rc != 0 ? in_frame(err, rc, s->option, f, " (nothing was scored)") : 0;
}

/* Every frame of s there, readable and of its first frame's size (and
 * channels, for the stylized frames, which are compared channel by
 * channel). */
static int check_sequence(sequence *s, const ts_frames *fr, int same_channels, char *err) {
  int n = ts_frame_pattern(s->pattern, err);
  if (n < 0) return n;
  if (n == 0)
    return ts_error(err, TS_EINVAL, "%s %s: put the frame number in the name (%%d or %%04d, e.g. shot/%%04d.png)",
                    s->option, s->pattern);
  char path[FLICKER_PATH], first[FLICKER_PATH];
  for (long f = fr->first; f <= fr->last; f++) {
    ts_image_info info;
    int rc = probe_frame(s, f, f == fr->first ? first : path, f == fr->first ? &s->first : &info, err);
    if (rc != 0) return rc;
    if (f > fr->first &&
        (info.width != s->first.width || info.height != s->first.height ||
         (same_channels && info.channels != s->first.channels)))
      return ts_error(err, TS_EINVAL,
                      "%s frame %ld (%s) is %dx%d with %d channels, frame %ld (%s) %dx%d with %d: every frame "
                      "must have the first one's size%s",
                      s->option, f, path, info.width, info.height, info.channels, fr->first, first,
                      s->first.width, s->first.height, s->first.channels, same_channels ? " and channels" : "");
  }
  return 0;
}

static int check_all(const flicker_opts *o, sequence *in, sequence *sty, char *err) {
  int rc = ts_flow_lib_load(err);
  if (rc == 0) rc = check_sequence(in, &o->fr, 0, err);
  if (rc == 0) rc = check_sequence(sty, &o->fr, 1, err);
  if (rc != 0) return rc;
  if (sty->first.width != in->first.width || sty->first.height != in->first.height)
    return ts_error(err, TS_EINVAL, "--image frames are %dx%d, --input frames %dx%d: the stylized frames must have "
                    "their inputs' size", sty->first.width, sty->first.height, in->first.width, in->first.height);
  if (in->first.width < TS_FLOW_MIN_SIDE || in->first.height < TS_FLOW_MIN_SIDE)
    return ts_error(err, TS_EINVAL, "--input frames are %dx%d: the optical flow needs at least %dx%d",
                    in->first.width, in->first.height, TS_FLOW_MIN_SIDE, TS_FLOW_MIN_SIDE);
  return 0;
}

/* ---- one frame, one step ---------------------------------------------- */

/* A frame in the forms a step uses: the input's luminance, the stylized
 * samples as floats in 8-bit units. */
typedef struct {
  uint8_t *luma;
  float *sty;
} frame;

static void frame_free(frame *fm) {
  free(fm->luma);
  free(fm->sty);
  *fm = (frame){0};
}

static int read_frame(const sequence *in, const sequence *sty, long f, frame *fm, char *err) {
  char path[FLICKER_PATH];
  ts_image img = {0};
  int w = in->first.width, h = in->first.height, c = sty->first.channels;
  fm->luma = malloc((size_t)w * h);
  fm->sty = malloc(sizeof(float) * (size_t)w * h * c);
  if (fm->luma == NULL || fm->sty == NULL) return ts_error(err, TS_ENOMEM, "out of memory for %dx%d frames", w, h);
  ts_frame_path(in->pattern, f, path, sizeof(path)); /* fits: checked */
  int rc = ts_image_read(path, &img, NULL, err);
  if (rc == 0) ts_image_luma8(&img, fm->luma);
  ts_image_free(&img);
  ts_frame_path(sty->pattern, f, path, sizeof(path));
  if (rc == 0) rc = ts_image_read(path, &img, NULL, err);
  for (int y = 0; rc == 0 && y < h; y++)
    for (int x = 0; x < w; x++)
      for (int k = 0; k < c; k++) fm->sty[((size_t)y * w + x) * c + k] = 255.0f * ts_image_sample(&img, x, y, k);
  ts_image_free(&img);
  return rc;
}

/* Scratch for a step: both flows, the warped frame, the occlusions. */
typedef struct {
  float *back, *fwd, *warped;
  uint8_t *occluded;
} step_buf;

static int step_buf_alloc(step_buf *b, int w, int h, int c, char *err) {
  b->back = malloc(sizeof(float) * 2 * (size_t)w * h);
  b->fwd = malloc(sizeof(float) * 2 * (size_t)w * h);
  b->warped = malloc(sizeof(float) * (size_t)w * h * c);
  b->occluded = malloc((size_t)w * h);
  return b->back && b->fwd && b->warped && b->occluded
             ? 0
             : ts_error(err, TS_ENOMEM, "out of memory for the flows of %dx%d frames", w, h);
}

static void step_buf_free(step_buf *b) {
  free(b->back);
  free(b->fwd);
  free(b->warped);
  free(b->occluded);
}

static int score_step(const frame *prev, const frame *cur, int w, int h, int c, step_buf *b, step_score *s,
                      char *err) {
  int rc = ts_flow_dis(cur->luma, prev->luma, w, h, b->back, err);
  if (rc == 0) rc = ts_flow_dis(prev->luma, cur->luma, w, h, b->fwd, err);
  if (rc != 0) return rc;
  size_t occluded = ts_flow_occlusion(b->back, b->fwd, w, h, b->occluded);
  ts_flow_warp(prev->sty, w, h, c, b->back, b->warped);
  double sum = 0;
  for (size_t i = 0; i < (size_t)w * h; i++)
    for (int k = 0; k < c && !b->occluded[i]; k++) {
      float d = cur->sty[i * c + k] - b->warped[i * c + k];
      sum += d < 0 ? -d : d;
    }
  size_t kept = (size_t)w * h - occluded;
  s->error = kept > 0 ? sum / ((double)kept * c) : 0.0;
  s->occluded = (double)occluded / ((double)w * h);
  return 0;
}

/* ---- the sequence and its report ------------------------------------ */

static int score_all(const flicker_opts *o, const sequence *in, const sequence *sty, step_score *steps,
                     char *err) {
  int w = in->first.width, h = in->first.height, c = sty->first.channels;
  frame prev = {0}, cur = {0};
  step_buf b = {0};
  int rc = step_buf_alloc(&b, w, h, c, err);
  if (rc == 0) rc = read_frame(in, sty, o->fr.first, &prev, err);
  for (long f = o->fr.first + 1; rc == 0 && f <= o->fr.last; f++) {
    rc = read_frame(in, sty, f, &cur, err);
    if (rc == 0) rc = score_step(&prev, &cur, w, h, c, &b, &steps[f - o->fr.first - 1], err);
    if (rc != 0) rc = in_frame(err, rc, NULL, f, "");
    frame_free(&prev);
    prev = cur;
    cur = (frame){0};
  }
  frame_free(&prev);
  step_buf_free(&b);
  return rc;
}

static void report(const flicker_opts *o, const step_score *steps, long n) {
  double sum = 0, occluded = 0;
  long worst = 0;
  for (long i = 0; i < n; i++) {
    sum += steps[i].error;
    occluded += steps[i].occluded;
    if (steps[i].error > steps[worst].error) worst = i;
  }
  long worst_frame = o->fr.first + worst + 1;
  if (!o->json) {
    printf("temporal error %.3f: mean over %ld steps (frames %ld..%ld) of the mean absolute difference per channel, "
           "8-bit units\n", sum / n, n, o->fr.first, o->fr.last);
    printf("worst step     %.3f: frame %ld against %ld\n", steps[worst].error, worst_frame, worst_frame - 1);
    printf("occluded       %.1f%% of the pixels, left out\n", 100.0 * occluded / n);
    return;
  }
  printf("{\"frames\": [%ld, %ld], \"steps\": %ld, \"mean\": %.4f, \"worst\": %.4f, \"worst_frame\": %ld, "
         "\"occluded\": %.4f, \"flow\": \"%s\", \"per_step\": [",
         o->fr.first, o->fr.last, n, sum / n, steps[worst].error, worst_frame, occluded / n, ts_flow_method());
  for (long i = 0; i < n; i++)
    printf("%s{\"frame\": %ld, \"error\": %.4f, \"occluded\": %.4f}", i > 0 ? ", " : "", o->fr.first + i + 1,
           steps[i].error, steps[i].occluded);
  printf("]}\n");
}

int ts_cmd_flicker(int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  flicker_opts o = {0};
  int rc = parse(argc, argv, &o, err);
  if (rc != 0) {
    fprintf(stderr, "texsyn flicker: %s\n", err);
    return 2;
  }
  sequence in = {"--input", o.input, {0}}, sty = {"--image", o.image, {0}};
  step_score *steps = NULL;
  rc = check_all(&o, &in, &sty, err);
  long n = o.fr.last - o.fr.first;
  if (rc == 0 && (steps = calloc((size_t)n, sizeof(*steps))) == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) rc = score_all(&o, &in, &sty, steps, err);
  if (rc == 0) report(&o, steps, n);
  else fprintf(stderr, "texsyn flicker: %s\n", err);
  free(steps);
  return rc == 0 ? 0 : 1;
}
