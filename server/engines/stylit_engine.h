/* stylit_engine.h - the stylization's scene as engines see it: the names
 * of its inputs and its spec keys. The stylize engine (stylit_engine.c)
 * and the energy engine (energy_engine.c) take the same scene, so a client
 * sends it, and the spool keeps it, the same way for both. */
#ifndef TS_STYLIT_ENGINE_H
#define TS_STYLIT_ENGINE_H

#include <stddef.h>

#include "engine.h"
#include "stylit.h"

/* The scene's inputs: "style", then per guide K "guide_src_K",
 * "guide_tgt_K" (the order of stylit.h's ts_stylit_in_*). */
void ts_stylit_scene_inputs(const ts_stylit_params *p, ts_engine_inputs *out);
/* Sets a guide's weight, spec key weight_K: 0, TS_EINVAL for a bad value,
 * TS_ENOENT for another key. */
int ts_stylit_weight_set(ts_stylit_params *p, const char *key, const char *value);
/* After parsing: 0, or TS_EINVAL when a weight was given for a guide the
 * job does not have (it would not survive format and parse). */
int ts_stylit_scene_complete(const ts_stylit_params *p, char *err);
/* Appends the guides' weight_K lines: the length, or TS_ETOOBIG. */
int ts_stylit_weights_format(const ts_stylit_params *p, char *buf, size_t cap);

#endif
