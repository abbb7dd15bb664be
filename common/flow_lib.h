/* flow_lib.h - the boundary between the programs and libtexsyn-flow.so.
 *
 * Optical flow is computed by OpenCV's DIS flow (flow_cv.cpp), built into
 * a shared object of its own and loaded with dlopen by flow_load.c on the
 * first flow call, as image I/O is (image_lib.h, dl_lib.h): OpenCV and the
 * C++ runtime stay out of the programs, and commands that never compute a
 * flow never load them. The library exports one symbol of ours, the table
 * below; everything else in it is hidden. */
#ifndef TS_FLOW_LIB_H
#define TS_FLOW_LIB_H

#include <stdint.h>

#ifdef __cplusplus
extern "C" {
#endif

#define TS_FLOW_LIB_NAME "libtexsyn-flow.so"
/* Overrides the search with one path (tests, unusual installs). */
#define TS_FLOW_LIB_ENV "TEXSYN_FLOW_LIB"

/* Each member is the flow.h function of the same name. */
typedef struct {
  int (*dis)(const uint8_t *from, const uint8_t *to, int w, int h, float *uv, char *err);
  const char *(*method)(void);
} ts_flow_lib;

/* Versioned like image_lib.h's table: change the name with any change to
 * ts_flow_lib or to what its functions compute, so that a library built
 * from other sources fails to load instead of being called wrongly. */
#define TS_FLOW_LIB_TABLE ts_flow_lib_v1
#define TS_FLOW_LIB_STR_(x) #x
#define TS_FLOW_LIB_STR(x) TS_FLOW_LIB_STR_(x)
#define TS_FLOW_LIB_TABLE_NAME TS_FLOW_LIB_STR(TS_FLOW_LIB_TABLE)

extern const ts_flow_lib TS_FLOW_LIB_TABLE;

#ifdef __cplusplus
}
#endif

#endif
