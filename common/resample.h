/* resample.h - an image at another size by area averaging: each output
 * pixel the mean of the input area it covers (fractional pixels weighed by
 * their overlap). For making inputs smaller (stylize --scale); the
 * arithmetic is plain double, so the bytes are the same on every machine. */
#ifndef TS_RESAMPLE_H
#define TS_RESAMPLE_H

#include "image.h"

/* out (allocated here) = in at w x h, its channels; 8- and 16-bit stay so
 * (rounded to nearest), half and float become float. 0, TS_EINVAL for a
 * size below 1, TS_ENOMEM. */
int ts_image_resample(const ts_image *in, int w, int h, ts_image *out, char *err);

#endif
