/* image.c - see image.h. Pixel helpers in plain C; file I/O is in
 * image_oiio.cpp.
 *
 * Every 8-bit conversion goes through one integer path so results never
 * depend on compiler floating-point flags (contraction, excess precision):
 * a sample is first made a 16-bit fixed-point value v in [0, 65535]
 * (8-bit k -> 257k exactly; half and float clamped to [0, 1] and rounded
 * to nearest-even), then narrowed with exact integer rounding. */
#include "image.h"

#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "image_meta.h"

size_t ts_pixtype_size(ts_pixtype t) {
  switch (t) {
  case TS_PIX_U8:
    return 1;
  case TS_PIX_U16:
  case TS_PIX_F16:
    return 2;
  case TS_PIX_F32:
    return 4;
  }
  return 0;
}

const char *ts_pixtype_name(ts_pixtype t) {
  switch (t) {
  case TS_PIX_U8:
    return "uint8";
  case TS_PIX_U16:
    return "uint16";
  case TS_PIX_F16:
    return "half";
  case TS_PIX_F32:
    return "float";
  }
  return "unknown";
}

int ts_image_alloc(ts_image *img, int width, int height, int channels, ts_pixtype type, char *err) {
  memset(img, 0, sizeof(*img));
  size_t tsize = ts_pixtype_size(type);
  if (width <= 0 || height <= 0)
    return ts_error(err, TS_EINVAL, "image size %dx%d: both must be positive", width, height);
  if (channels < 1 || channels > TS_IMAGE_MAX_CHANNELS)
    return ts_error(err, TS_EINVAL, "%d channels: an image has 1 to %d", channels,
                    TS_IMAGE_MAX_CHANNELS);
  if (tsize == 0) return ts_error(err, TS_EINVAL, "pixel type %d is not a ts_pixtype", (int)type);
  /* Overflow-checked width * height * channels * tsize. */
  size_t n = (size_t)width;
  size_t per_pixel = (size_t)channels * tsize;
  if ((size_t)height > SIZE_MAX / n || n * (size_t)height > SIZE_MAX / per_pixel)
    return ts_error(err, TS_ENOMEM,
                    "%dx%d image of %d %s channels is larger than memory can "
                    "address",
                    width, height, channels, ts_pixtype_name(type));
  n *= (size_t)height;
  img->pixels = calloc(n, per_pixel);
  if (img->pixels == NULL)
    return ts_error(err, TS_ENOMEM,
                    "out of memory for a %dx%d image of %d %s channels "
                    "(%zu bytes)",
                    width, height, channels, ts_pixtype_name(type), n * per_pixel);
  img->width = width;
  img->height = height;
  img->channels = channels;
  img->type = type;
  return 0;
}

void ts_image_free(ts_image *img) {
  if (img == NULL) return;
  free(img->pixels);
  ts_meta_free(img->meta);
  memset(img, 0, sizeof(*img));
}

/* IEEE half bits to float. Every half is exactly representable as a float,
 * so this is exact: normals and infinities/NaNs move their fields over,
 * subnormals are mantissa * 2^-24 (a product by a power of two). */
static float ts_half_to_float(uint16_t h) {
  uint32_t sign = (uint32_t)(h & 0x8000u) << 16;
  uint32_t exp = (h >> 10) & 0x1fu;
  uint32_t man = h & 0x3ffu;
  if (exp == 0) {
    float f = (float)man * 0x1p-24f;
    return sign ? -f : f;
  }
  uint32_t bits = sign | (man << 13);
  bits |= exp == 0x1f ? 0x7f800000u : (exp + 112u) << 23; /* rebias 15->127 */
  float f;
  memcpy(&f, &bits, sizeof(f));
  return f;
}

static size_t ts_index(const ts_image *img, int x, int y, int c) {
  return ((size_t)y * (size_t)img->width + (size_t)x) * (size_t)img->channels + (size_t)c;
}

float ts_image_sample(const ts_image *img, int x, int y, int c) {
  size_t i = ts_index(img, x, y, c);
  switch (img->type) {
  case TS_PIX_U8:
    return ((const uint8_t *)img->pixels)[i] / 255.0f;
  case TS_PIX_U16:
    return ((const uint16_t *)img->pixels)[i] / 65535.0f;
  case TS_PIX_F16:
    return ts_half_to_float(((const uint16_t *)img->pixels)[i]);
  case TS_PIX_F32:
    return ((const float *)img->pixels)[i];
  }
  return 0.0f;
}

/* [0, 1] float to 16-bit fixed point. NaN and negatives give 0. A single
 * multiply then lrintf (round to nearest-even): nothing to contract. */
static uint32_t ts_unit16(float f) {
  if (!(f > 0.0f)) return 0;
  if (f >= 1.0f) return 65535;
  return (uint32_t)lrintf(f * 65535.0f);
}

/* Sample i (flat index) as 16-bit fixed point. */
static uint32_t ts_fixed16(const ts_image *img, size_t i) {
  switch (img->type) {
  case TS_PIX_U8:
    return ((const uint8_t *)img->pixels)[i] * 257u;
  case TS_PIX_U16:
    return ((const uint16_t *)img->pixels)[i];
  case TS_PIX_F16:
    return ts_unit16(ts_half_to_float(((const uint16_t *)img->pixels)[i]));
  case TS_PIX_F32:
    return ts_unit16(((const float *)img->pixels)[i]);
  }
  return 0;
}

void ts_image_channel8(const ts_image *img, int c, uint8_t *out) {
  size_t n = (size_t)img->width * (size_t)img->height;
  size_t ch = (size_t)img->channels;
  /* round(v / 257): 257 is odd, so v / 257 is never a tie. */
  for (size_t p = 0; p < n; p++)
    out[p] = (uint8_t)((ts_fixed16(img, p * ch + (size_t)c) + 128) / 257);
}

void ts_image_luma8(const ts_image *img, uint8_t *out) {
  if (img->channels < 3) {
    ts_image_channel8(img, 0, out);
    return;
  }
  size_t n = (size_t)img->width * (size_t)img->height;
  size_t ch = (size_t)img->channels;
  /* Y8 = round((299 R + 587 G + 114 B) / 1000 / 257), ties up; at most
   * 65535000 + 128500, well inside uint32_t. For 8-bit input this equals
   * round((299 R + 587 G + 114 B) / 1000) on the 8-bit values. */
  for (size_t p = 0; p < n; p++) {
    size_t i = p * ch;
    uint32_t y =
        299u * ts_fixed16(img, i) + 587u * ts_fixed16(img, i + 1) + 114u * ts_fixed16(img, i + 2);
    out[p] = (uint8_t)((y + 128500u) / 257000u);
  }
}

void ts_image_copy_pixel(ts_image *dst, int dx, int dy, const ts_image *src, int sx, int sy) {
  size_t tsize = ts_pixtype_size(src->type); /* same type and channels */
  uint8_t *d = (uint8_t *)dst->pixels + ts_index(dst, dx, dy, 0) * tsize;
  const uint8_t *s = (const uint8_t *)src->pixels + ts_index(src, sx, sy, 0) * tsize;
  memcpy(d, s, (size_t)src->channels * tsize);
}
