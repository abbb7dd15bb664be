/* segment_input.h - a segmentation's parameters (declared once, param.h)
 * and inputs: the limits, the struct, the inputs' order, their checks,
 * the classes of the label rasters and the planes the search compares
 * (segment_input.c). segment.h says what the method does with them. */
#ifndef TS_SEGMENT_INPUT_H
#define TS_SEGMENT_INPUT_H

#include <stddef.h>
#include <stdint.h>

#include "image.h"
#include "param.h"
#include "plane.h"

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

/* ---- inputs as planes (segment_input.c) -------------------------------- */

/* The classes of checked label rasters. */
void ts_seg_classes_find(const ts_seg_params *p, const ts_image *const *in, ts_seg_classes *c);
/* Class map (w x h bytes) of a checked label or truth raster. */
void ts_seg_class_map(const ts_seg_classes *c, const ts_image *lbl, uint8_t *out);
/* The search planes of an image: its luminance, or its three colour
 * channels (rgb), 8-bit, into planes[0..]. 0 or TS_ENOMEM. */
int ts_seg_planes(const ts_image *img, int rgb, ts_plane *planes);

#endif
