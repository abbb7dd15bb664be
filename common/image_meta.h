/* image_meta.h - internal glue between image.c and image_oiio.cpp.
 *
 * ts_meta is a C++ object (an OpenImageIO attribute list) that C code only
 * ever holds by pointer; these are the few C-visible functions that create
 * and destroy it outside of ts_image_read. In the programs they forward to
 * libtexsyn-image.so (image_load.c), like image.h's file functions. */
#ifndef TS_IMAGE_META_H
#define TS_IMAGE_META_H

#include "image.h"

#ifdef __cplusplus
extern "C" {
#endif

/* Most channels an image may have: more means a corrupt header or a
 * multi-layer render, neither of which the engines can use. */
#define TS_IMAGE_MAX_CHANNELS 16

/* Frees meta (NULL is fine). */
void ts_meta_free(ts_meta *meta);

/* Sets the string attribute `name` (e.g. "ImageDescription", "Software"),
 * replacing any attribute of that name; creates *meta if it is NULL.
 * 0, TS_EINVAL, TS_ENOMEM, or TS_ENOTSUP if the image library cannot be
 * loaded (ts_image_lib_load tells why). */
int ts_meta_set(ts_meta **meta, const char *name, const char *value);

/* Replaces *to (freed if not NULL) with a copy of from (NULL: empty), to
 * change without touching from. 0, TS_EINVAL, TS_ENOMEM or TS_ENOTSUP as
 * ts_meta_set. */
int ts_meta_copy(const ts_meta *from, ts_meta **to);

#ifdef __cplusplus
}
#endif

#endif
