/* jobspec.h - a job as text: what a client submits, what the spool keeps
 * (job.spec) and what a restarted coordinator reads back.
 *
 * One `key=value` per line, keys in any order, unknown keys refused (a
 * newer client's option must not be silently dropped). `engine` names the
 * engine (server/engines/engine.h; absent = mrf, as spooled before engines
 * had names); every other key is the engine's: its parameters, and its
 * outputs, each asked for by key, e.g. for mrf
 *
 *   engine=mrf  size=1024x1024  levels=5  wn=7  wb=3  parity=0  usage_weight=0
 *   coarse_weight=1  refine=2  seed=1  rgb_search=0  max_pixels=N
 *   output=png  copy_map=png  copy_map_raw=1  usage_map=tif  report=1
 *
 * An image output's value is a file extension (the format of the file the
 * coordinator writes), empty or absent meaning not wanted. A flag output is
 * 0 or 1. The engine's first output, its result (an image, or a flag
 * output such as energy's JSON), is required.
 *
 * `name` (optional, any engine) is the file name the client gave the
 * result (-o's last part), for `texsyn status` to show; it changes
 * nothing in the job. Printable ASCII, 1..TS_JOBSPEC_NAME_LEN - 1 bytes. */
#ifndef TS_JOBSPEC_H
#define TS_JOBSPEC_H

#include <stddef.h>

#include "engine.h"

#define TS_JOBSPEC_NAME_LEN 128

typedef struct {
  const ts_engine *engine;
  ts_engine_params params; /* the engine's parameter struct */
  ts_engine_wants wants;   /* the outputs asked for */
  char name[TS_JOBSPEC_NAME_LEN]; /* the result's file name on the client; "" if not given */
} ts_jobspec;

/* A spec for `engine` (NULL: the default engine) with its defaults and
 * only the result: an image as png, or a flag output. */
void ts_jobspec_default(ts_jobspec *s, const ts_engine *engine);
/* Sets s->name from a path's last part, other bytes than printable ASCII
 * as '?' (cut to fit). */
void ts_jobspec_set_name(ts_jobspec *s, const char *path);
/* Writes the spec; returns its length, or TS_ETOOBIG if cap is too small. */
int ts_jobspec_format(const ts_jobspec *s, char *buf, size_t cap);
/* Parses len bytes (need not be NUL-terminated). Every line is checked;
 * the first problem is reported with its line number. Parameter ranges
 * are the engine's business (its check). */
int ts_jobspec_parse(const char *text, size_t len, ts_jobspec *s, char *err);
/* 1 if ext is a non-empty extension a spec accepts (letters and digits,
 * shorter than TS_EXT_LEN), else 0. */
int ts_ext_valid(const char *ext);
/* The image formats texsyn writes, by extension (each one's pixel type and
 * lossless defaults are known; any other, even one OpenImageIO could write,
 * is refused before a job runs: on the client, and by a coordinator's spec
 * parse for a client that skipped that check). */
#define TS_IMAGE_EXTS_HELP ".png, .jpg, .jpeg, .tif, .tiff or .exr"
/* 1 if an image output takes extension ext (any case): an image format, or
 * the output's own (own_ext), else 0. */
int ts_output_ext_ok(const ts_engine_output *out, const char *ext);
/* 1 if extensions a and b name one format (any case; jpg = jpeg, tif =
 * tiff), else 0. */
int ts_ext_same_format(const char *a, const char *b);
/* The extension of a path ("png" for "a/b.png"), or "" without one. */
const char *ts_path_ext(const char *path);

#endif
