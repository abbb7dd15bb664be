/* repetition.h - how much of a synthesised image repeats, from its copy
 * map (the reference pixel each output pixel came from).
 *
 * Why a score and not a look: a user who lays a 96x52 crop over a
 * 8192² scene sees stripes only when zooming in; a number in the report
 * says it before anyone looks. The copy map is cut into *patches*: the
 * 4-connected areas whose pixels share one offset (source - position),
 * i.e. one piece copied verbatim. A patch of at least side x side pixels
 * is *large*: a piece big enough to be recognised. A pixel of a large
 * patch *repeats* when its source pixel is also the source of a pixel of
 * another large patch (within one patch a source pixel is used once, so
 * two uses are two patches). The score is the share of the image's pixels
 * that repeat: 0 when no large piece of the reference shows twice, 1 when
 * the image is large pieces that all show elsewhere too.
 *
 * Sources are told apart by a per-pixel source id as well (an aerial
 * scene's classes each copy from their own reference): the same (x, y)
 * in two references is not a repeat. */
#ifndef TS_REPETITION_H
#define TS_REPETITION_H

#include <stdint.h>

#define TS_REPETITION_SIDE 16 /* the default side of a large patch */

typedef struct {
  int side;             /* large patches have >= side * side pixels */
  uint64_t pixels;      /* the image's, with a source */
  uint64_t large;       /* in large patches */
  uint64_t repeated;    /* in large patches whose source shows twice */
  uint64_t patches;     /* patches, and large ones */
  uint64_t large_patches;
  double share;         /* repeated / pixels, 0 for no pixels */
} ts_repetition;

/* The score of a w x h copy map (x then y per pixel, into references of
 * rw x rh; a pixel whose x is UINT32_MAX has no source and is left out),
 * with source ids (NULL: one reference; else nsrc ids per pixel, each
 * < nsrc) and large patches of side x side. 0, TS_EINVAL (a source
 * outside its reference) or TS_ENOMEM, with a message. */
int ts_repetition_score(const uint32_t *copy, const uint8_t *src_id, int nsrc, int w, int h, int rw, int rh,
                        int side, ts_repetition *out, char *err);

#endif
