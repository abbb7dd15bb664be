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
 * nothing in the job. Printable ASCII, 1..TS_JOBSPEC_NAME_LEN - 1 bytes.
 *
 * `sequence` and its five companions (optional, all or none) say that the
 * job is one frame of a `texsyn video` sequence, for the operations page
 * to show the sequence's frames together as they finish; like `name` they
 * change nothing in the job:
 *
 *   sequence=0123456789abcdef   the run's id: 16 hex digits (a rerun of the
 *                               same work has the same one)
 *   sequence_name=out_%04d.png  the output pattern's last part
 *   sequence_frames=1..48       the sequence's frames
 *   sequence_jobs=68            the stylize jobs it takes: every chain's frames
 *   sequence_chain=24..47       this job's chain: from key 24 towards 47
 *   sequence_frame=30           this job's frame, past the key, up to 47 */
#ifndef TS_JOBSPEC_H
#define TS_JOBSPEC_H

#include <stddef.h>
#include <stdint.h>

#include "engine.h"

#define TS_JOBSPEC_NAME_LEN 128
#define TS_JOBSPEC_SEQ_ID_LEN 17 /* 16 hex digits */
#define TS_JOBSPEC_FRAME_MAX 999999L

/* A frame of a sequence (above): id "" when the job is none. */
typedef struct {
  char id[TS_JOBSPEC_SEQ_ID_LEN];
  char name[TS_JOBSPEC_NAME_LEN];
  long first, last;     /* the sequence's frames */
  uint32_t jobs;        /* the stylize jobs of all its chains */
  long key, end, frame; /* the chain from key towards end; this job's frame */
  unsigned given;       /* the parser's: which of the six keys were read */
} ts_jobspec_seq;

typedef struct {
  const ts_engine *engine;
  ts_engine_params params; /* the engine's parameter struct */
  ts_engine_wants wants;   /* the outputs asked for */
  char name[TS_JOBSPEC_NAME_LEN]; /* the result's file name on the client; "" if not given */
  ts_jobspec_seq seq;             /* the sequence it is a frame of, if any */
} ts_jobspec;

/* A spec for `engine` (NULL: the default engine) with its defaults and
 * only the result: an image as png, or a flag output. */
void ts_jobspec_default(ts_jobspec *s, const ts_engine *engine);
/* Sets s->name from a path's last part, other bytes than printable ASCII
 * as '?' (cut to fit). */
void ts_jobspec_set_name(ts_jobspec *s, const char *path);
/* What ts_jobspec_set_name makes of a path, into out (cap bytes). */
void ts_jobspec_name_of(const char *path, char *out, size_t cap);
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
