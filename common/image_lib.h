/* image_lib.h - the boundary between the programs and libtexsyn-image.so.
 *
 * Decoding and encoding (image_oiio.cpp, with image_check.c and
 * tiff_tags.c) are built into a shared object of their own, loaded with
 * dlopen by image_load.c on the first image call. OpenImageIO pulls in
 * some 260 shared libraries whose loading and symbol binding cost a
 * process 0.2 s or more at start; commands that never touch an image file
 * (texsyn status, watch, workers, cancel, fetch, the worker daemon) must
 * not pay that. The programs are linked without OpenImageIO, so nothing
 * outside the library can call it or the shim directly: image.h's file
 * functions resolve to image_load.c, which forwards through this table.
 *
 * Of texsyn's own symbols the library exports one, TS_IMAGE_LIB_TABLE, a
 * table of the shim's entry points; everything else of ours in it, its
 * own copies of image.c, error.c and the checks included, is hidden.
 * Inside the library the names of image.h are the shim's implementations;
 * in the programs they are image_load.c's forwarders. */
#ifndef TS_IMAGE_LIB_H
#define TS_IMAGE_LIB_H

#include "image.h"

#ifdef __cplusplus
extern "C" {
#endif

/* The file name, looked for next to the running executable, then in
 * ../lib/texsyn/ from there (where `make install` puts it). */
#define TS_IMAGE_LIB_NAME "libtexsyn-image.so"
/* Overrides the search with one path (tests, unusual installs). */
#define TS_IMAGE_LIB_ENV "TEXSYN_IMAGE_LIB"

/* Each member is the image.h function of the same name. */
typedef struct {
  int (*read)(const char *path, ts_image *img, const ts_image_limits *limits, char *err);
  int (*read_mem)(const char *name, const void *data, size_t len, ts_image *img,
                  const ts_image_limits *limits, char *err);
  int (*probe_mem)(const char *name, const void *data, size_t len, const ts_image_limits *limits,
                   ts_image_info *info, char *err);
  int (*write)(const char *path, const ts_image *img, const ts_meta *meta_from, char *err);
  int (*meta_get)(const ts_meta *meta, const char *name, char *out, size_t outlen);
  int (*meta_set)(ts_meta **meta, const char *name, const char *value);
  void (*meta_free)(ts_meta *meta);
  int (*meta_copy)(const ts_meta *from, ts_meta **to);
  int (*movie_probe)(const char *path, const ts_image_limits *limits, ts_movie_info *info, char *err);
  int (*movie_read)(const char *path, long first, long last, const ts_image_limits *limits, ts_movie_frame_fn each,
                    void *ctx, char *err);
  int (*write_animation)(const char *path, const ts_image *frames, int n, double fps, char *err);
  int (*regions_open)(const char *path, const ts_image_limits *limits, ts_image_info *info, ts_meta **meta,
                      ts_image_regions **out, char *err);
  int (*regions_read)(ts_image_regions *r, int x, int y, int w, int h, void *dst, char *err);
  void (*regions_close)(ts_image_regions *r);
  int (*writer_create)(const char *path, int w, int h, int channels, int tile, const ts_meta *meta_from,
                       ts_image_writer **out, char *err);
  int (*writer_put)(ts_image_writer *wr, int y, int h, const uint8_t *px, char *err);
  int (*writer_finish)(ts_image_writer *wr, char *err);
  void (*writer_abort)(ts_image_writer *wr);
} ts_image_lib;

/* The table's symbol carries a version: change it with any change to
 * ts_image_lib (or to the structs of image.h), so that a library built
 * from other sources fails to load, naming the symbol it lacks, instead
 * of being called through the wrong layout. */
#define TS_IMAGE_LIB_TABLE ts_image_lib_v4
#define TS_IMAGE_LIB_STR_(x) #x
#define TS_IMAGE_LIB_STR(x) TS_IMAGE_LIB_STR_(x)
#define TS_IMAGE_LIB_TABLE_NAME TS_IMAGE_LIB_STR(TS_IMAGE_LIB_TABLE)

extern const ts_image_lib TS_IMAGE_LIB_TABLE;

#ifdef __cplusplus
}
#endif

#endif
