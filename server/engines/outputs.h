/* outputs.h - side outputs every synthesis engine may write: a copy map
 * (or NNF) as an image and raw, a usage map, a float map. (The MRF's report is
 * mrf_report.h's.) */
#ifndef TS_OUTPUTS_H
#define TS_OUTPUTS_H

#include <stdint.h>


/* 16-bit RGB: red = x / (ref_w - 1), green = y / (ref_h - 1) (seed §3.1). */
int ts_write_copy_map_image(const char *path, const uint32_t *map, int w, int h, int ref_w,
                            int ref_h, char *err);
/* Raw: w*h pairs (x, y) of little-endian uint32, row-major, no header. */
int ts_write_copy_map_raw(const char *path, const uint32_t *map, int w, int h, char *err);
/* .tif/.tiff/.exr: float counts; other formats: counts / max. */
int ts_write_usage_map(const char *path, const uint32_t *usage, int w, int h, char *err);
/* A map of w*h floats (an error map): .tif/.tiff/.exr: the floats; other
 * formats: divided by the largest (all 0 stays 0). */
int ts_write_float_map(const char *path, const float *map, int w, int h, char *err);
#endif
