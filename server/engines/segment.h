/* segment.h - supervised texture segmentation with the synthesis machinery
 * (seed 002 §5.2, "iMRF"; digest Part 3.2): every pixel of an input image
 * takes the class of the training pixel whose window looks most like its
 * own - 1-NN classification through the same exact search service the
 * synthesis uses.
 *
 * Inputs: the image to segment, and 1..TS_SEG_MAX_PAIRS training pairs,
 * each a training image and its label raster (same size, one 8- or 16-bit
 * channel). Every value a label raster holds is a class (0 included: there
 * is no "unlabelled" value); at most TS_SEG_MAX_CLASSES distinct values
 * over all rasters. Optionally a truth raster (the input's size, values
 * among the classes), against which accuracy is counted. Output: a label
 * raster of the input's size carrying the training label values, 16-bit
 * if a label raster is, else 8-bit.
 *
 * Method:
 *
 *   vectors   N x N windows (N odd) of the luminance (or of the three
 *             colour channels), one part of weight 1, compared by L1.
 *             Reference windows lie wholly inside a training image; the
 *             input is read past its edges as the edge pixel repeated, so
 *             every input pixel has a window centred on it. A reference
 *             window's class is the label of its centre pixel.
 *   level     every input pixel takes the class of the nearest reference
 *             window over all training images: one reference set per
 *             training image, the results merged by distance, ties to the
 *             earlier image, then (the search's rule) the lower index - the
 *             lowest index of the training images' windows taken in order.
 *             Queries are independent: big batches, any order.
 *   levels    L Gaussian pyramid levels (plane.h), each segmented on its
 *             own (not coupled, §5.2.3); the label rasters' level l is
 *             their pixel (x << l, y << l), the centre of the level-l
 *             pixel's Gaussian.
 *   weights   (L > 1) self-segmentation: each training image is split in
 *             two halves across its longer side; at every level each half
 *             is segmented against the other half and all other training
 *             images; rate_l^k = the share of class-k pixels it labels k;
 *             w_l^k = rate_l^k / sum_l rate_l^k (a class whose rate is 0
 *             at every level weighs its levels equally).
 *   fusion    every level's labels taken at level 0 by the nearest level-l
 *             pixel (round(x / 2^l), clamped to the level); per pixel the
 *             class with the largest sum_l w_l^k [label_l = k] wins, ties to
 *             the lower class value. One level: its labels as they are.
 *   denoise   (MIN_AREA > 0) 4-connected regions of one class smaller than
 *             MIN_AREA pixels take the class most of their border touches
 *             (pixel edges counted, ties to the lower class value); passes
 *             repeat until none is left (ts_seg_denoise says how it stays
 *             deterministic).
 *
 * Exact: no lossy shortcut; the result depends on the inputs and
 * parameters only, never on the threads, the workers or the batching. */
#ifndef TS_SEGMENT_H
#define TS_SEGMENT_H

#include <stddef.h>
#include <stdint.h>

#include "image.h"
#include "segment_input.h"
#include "segment_post.h"
#include "progress.h"
#include "search.h"

/* ---- running (segment.c) ----------------------------------------------- */

typedef struct {
  int w, h;                       /* the input at this level */
  uint64_t queries, self_queries; /* input pixels; training pixels self-segmented */
  uint64_t pairs;                 /* comparisons */
  double seconds, self_seconds;   /* the level, and its self-segmentation */
  uint64_t correct;               /* with a truth: pixels this level alone labels right */
} ts_seg_level_stats;

typedef struct {
  ts_image labels; /* the output */
  ts_seg_classes classes;
  int levels;
  ts_seg_level_stats level[TS_SEG_MAX_LEVELS];
  /* Self-segmentation counts, rates and weights, levels x classes. */
  uint64_t self_correct[TS_SEG_MAX_LEVELS * TS_SEG_MAX_CLASSES], self_total[TS_SEG_MAX_LEVELS * TS_SEG_MAX_CLASSES];
  double rate[TS_SEG_MAX_LEVELS * TS_SEG_MAX_CLASSES], weight[TS_SEG_MAX_LEVELS * TS_SEG_MAX_CLASSES];
  ts_seg_denoise_stats denoise;
  double seconds, fuse_seconds, denoise_seconds;
  /* With a truth: per class its pixels, and those labelled right before
   * and after noise reduction. */
  int has_truth;
  uint64_t truth_pixels[TS_SEG_MAX_CLASSES], correct_before[TS_SEG_MAX_CLASSES], correct_after[TS_SEG_MAX_CLASSES];
} ts_seg_result;

/* Runs a checked job (ts_seg_check). 0, or a TS_E* code with a message. */
int ts_seg_run(const ts_seg_params *p, const ts_image *const *in, ts_search *search, const ts_progress_hooks *h,
               ts_seg_result *res, char *err);
void ts_seg_result_free(ts_seg_result *res);

/* The accuracy table the CLI prints with --truth: per class its pixels in
 * the truth and the share labelled right before and after noise
 * reduction (of MIN_AREA denoise), then overall. The length, or
 * TS_ETOOBIG. */
int ts_seg_accuracy_text(const ts_seg_result *res, int denoise, char *buf, size_t cap);

#endif
