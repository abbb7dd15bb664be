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
#include "param.h"
#include "progress.h"
#include "search.h"

#define TS_SEG_MAX_PAIRS 8       /* a reference set each: the search's 8 sets at once */
#define TS_SEG_MAX_LEVELS 6
#define TS_SEG_MAX_WINDOW 31
#define TS_SEG_MAX_CLASSES 256   /* class indices are bytes */
#define TS_SEG_MAX_DENOISE 1000000000
#define TS_SEG_MAX_PLANES 3

typedef struct {
  int pairs;    /* training pairs, 1..TS_SEG_MAX_PAIRS */
  int levels;   /* 1..TS_SEG_MAX_LEVELS (3) */
  int window;   /* N: odd, 3..TS_SEG_MAX_WINDOW (9) */
  int denoise;  /* MIN_AREA in level-0 pixels, 0..TS_SEG_MAX_DENOISE (0: off) */
  int rgb;      /* 1: windows of the three colour channels, else luminance */
  int truth;    /* 1: the last input is a truth raster */
  uint64_t max_pixels;
} ts_seg_params;

/* Inputs in the engine's order: the input, per pair K its training image
 * and its labels, then the truth if any. */
enum { TS_SEG_IN_INPUT = 0 };
static inline int ts_seg_in_train(int k) { return 1 + 2 * k; }
static inline int ts_seg_in_labels(int k) { return 2 + 2 * k; }
static inline int ts_seg_in_truth(const ts_seg_params *p) { return 1 + 2 * p->pairs; }
/* How many inputs a job with these parameters takes (pairs bounded). */
int ts_seg_ninputs(const ts_seg_params *p);

/* The parameters' declaration (param.h) and their defaults. */
extern const ts_param ts_seg_param_table[];
void ts_seg_params_default(ts_seg_params *p);

/* ---- checks (segment_input.c) -------------------------------------------
 *
 * Problems are listed one per line, each naming its input by names[k]
 * (the CLI passes its options and paths, the engine the inputs' roles). */

/* Every problem the parameters and the inputs' headers show: ranges,
 * sizes (each label raster and the truth against their image), channels,
 * pixel types, the coarsest level (and its self-segmentation halves)
 * against the window. 0 or TS_EINVAL. */
int ts_seg_check_headers(const ts_seg_params *p, const ts_image_info *info, const char *const *names, char *msg,
                         size_t len);
/* The header check, then the label values: at most TS_SEG_MAX_CLASSES
 * distinct, and the truth holding none that no label raster has. */
int ts_seg_check(const ts_seg_params *p, const ts_image *const *in, const char *const *names, char *msg, size_t len);
/* The names the engine gives the inputs in messages ("--input", "--train
 * #1", "--labels #1", ..., "--truth"): ninputs entries of 32 bytes. */
#define TS_SEG_NAME_LEN 32
void ts_seg_role_names(const ts_seg_params *p, char (*names)[TS_SEG_NAME_LEN]);

/* The classes: the distinct label values of all label rasters, ascending
 * (class k has value value[k]); wide when a raster is 16-bit. */
typedef struct {
  int n;
  uint16_t value[TS_SEG_MAX_CLASSES];
  int wide;
} ts_seg_classes;

/* ---- the pieces after the search (segment_post.c) ----------------------
 *
 * Class maps are bytes (class indices), row-major. */

/* The level-l pixel nearest to level-0 coordinate x0 on a level of n
 * pixels: round(x0 / 2^l), clamped. */
static inline int ts_seg_nearest(int x0, int l, int n) {
  int x = l > 0 ? (x0 + (1 << (l - 1))) >> l : x0;
  return x < n ? x : n - 1;
}

/* rate and weight (levels x nclass, level-major) from the self-segmentation
 * counts: rate = correct / total (-1 where total is 0: no pixel of the
 * class at that level), weight = rate / sum over levels of the rates
 * (missing rates as 0; all levels equal when that sum is 0). */
void ts_seg_weights(int levels, int nclass, const uint64_t *correct, const uint64_t *total, double *rate,
                    double *weight);
/* out (w x h) = the weighted vote of the levels' maps lab[l] (lw[l] x
 * lh[l]), weights as ts_seg_weights makes them; ties to the lower class. */
void ts_seg_fuse(int levels, int nclass, const uint8_t *const *lab, const int *lw, const int *lh, const double *weight,
                 int w, int h, uint8_t *out);
/* out (w x h) = level l's map (lw x lh) at level 0, nearest pixel. */
void ts_seg_upsample(const uint8_t *lab, int lw, int lh, int l, int w, int h, uint8_t *out);

/* 4-connected regions of equal class: comp[i] = the region of pixel i,
 * regions numbered in the raster order of their first pixel; *n their
 * count. 0 or TS_ENOMEM. */
int ts_seg_components(const uint8_t *lab, int w, int h, uint32_t *comp, uint32_t *n);

typedef struct {
  uint32_t merged; /* regions given to a neighbour */
  uint32_t passes;
} ts_seg_denoise_stats;

/* Noise reduction in place: regions (as above) of fewer than min_area
 * pixels take the class their border touches most. A pass numbers the
 * regions, then takes the small ones smallest first (ties: the first in
 * raster order); a region next to one already changed in this pass waits
 * for the next (its size or its border may have changed), so every change
 * sees exact regions. Each change joins a region to a neighbour, so the
 * passes end; a region with no border (the whole image) stays. 0 or
 * TS_ENOMEM. */
int ts_seg_denoise(uint8_t *lab, int w, int h, uint32_t min_area, ts_seg_denoise_stats *st);

/* Per class: pixels[k] += truth pixels of class k, correct[k] += those pred
 * labels k too (n pixels). */
void ts_seg_count(const uint8_t *pred, const uint8_t *truth, size_t n, uint64_t *pixels, uint64_t *correct);

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

typedef struct {
  ts_progress_fn *progress; /* may be NULL */
  void *progress_ctx;
} ts_seg_hooks;

/* Runs a checked job (ts_seg_check). 0, or a TS_E* code with a message. */
int ts_seg_run(const ts_seg_params *p, const ts_image *const *in, ts_search *search, const ts_seg_hooks *h,
               ts_seg_result *res, char *err);
void ts_seg_result_free(ts_seg_result *res);

/* The accuracy table the CLI prints with --truth: per class its pixels in
 * the truth and the share labelled right before and after noise
 * reduction (of MIN_AREA denoise), then overall. The length, or
 * TS_ETOOBIG. */
int ts_seg_accuracy_text(const ts_seg_result *res, int denoise, char *buf, size_t cap);

/* ---- inputs as planes (segment_input.c) -------------------------------- */

/* The classes of checked label rasters. */
void ts_seg_classes_find(const ts_seg_params *p, const ts_image *const *in, ts_seg_classes *c);
/* Class map (w x h bytes) of a checked label or truth raster. */
void ts_seg_class_map(const ts_seg_classes *c, const ts_image *lbl, uint8_t *out);
/* The search planes of an image: its luminance, or its three colour
 * channels (rgb), 8-bit, into planes[0..]. 0 or TS_ENOMEM. */
int ts_seg_planes(const ts_image *img, int rgb, ts_plane *planes);

#endif
