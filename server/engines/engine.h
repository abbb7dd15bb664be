/* engine.h - what every engine offers the rest of texsyn: one operations
 * table per engine, chosen by the job spec's `engine` key.
 *
 * The job queue and spool (server/jobs/), the job spec (jobspec.c, here)
 * and the CLI's embedded runs call engines only through this table, so a
 * new engine (stylization, aerial, segmentation) lands by adding a table
 * to the registry (engine.c), without touching them. An engine sees the
 * search interface (common/search/search.h) and nothing of the daemon, the
 * wire or the CLI: the same code runs embedded and on a cluster.
 *
 * An engine's parameters are its own struct, stored in a ts_engine_params
 * buffer; it reads and writes them as `key=value` spec lines. Its inputs
 * are named images (ts_engine_inputs): which ones a job takes follows from
 * its parameters (a stylization's guide count), the client sends them
 * under those names, the spool keeps them under them. Its results are
 * named files (ts_engine_output): the spec asks for each by key, the
 * spool keeps them under their file names, the CLI writes them to paths. */
#ifndef TS_ENGINE_H
#define TS_ENGINE_H

#include <stdatomic.h>
#include <stddef.h>
#include <stdint.h>

#include "image.h"
#include "param.h"
#include "progress.h"
#include "search.h"

#define TS_ENGINE_PARAMS_MAX 8192 /* bytes of any engine's parameter struct */
#define TS_ENGINE_MAX_OUTPUTS 8
#define TS_ENGINE_MAX_INPUTS 34 /* a style, 16 guide pairs and the image energy scores */
#define TS_ENGINE_KEY_LEN 32    /* an input name's bytes, NUL included */
#define TS_EXT_LEN 16
/* Largest output width or height a spec (and the command line) takes. */
#define TS_OUTPUT_SIDE_MAX 1000000

/* Storage for an engine's parameter struct, aligned for any member. */
typedef union {
  max_align_t align_;
  unsigned char bytes[TS_ENGINE_PARAMS_MAX];
} ts_engine_params;

typedef enum {
  TS_OUTPUT_IMAGE, /* spec value: a file extension (the format); file: stem.EXT */
  TS_OUTPUT_FLAG   /* spec value: 0 or 1; file: the name as given */
} ts_output_kind;

typedef struct {
  const char *key;  /* spec key, e.g. "copy_map" */
  const char *file; /* spool file: stem ("copymap") or name ("report.json") */
  ts_output_kind kind;
  /* A side output's command-line option and its --help ("copy-map");
   * NULL for the result (-o) and the report (--report), every job's. */
  const char *flag, *help;
  /* An image output's format of its own besides the image formats
   * (jobspec.h), as an extension: "raw" for stylize's NNF; else NULL. */
  const char *own_ext;
  /* 1: run writes it itself, as it goes, to hooks->output_paths[k] (and
   * leaves nothing under that name if it fails); write_output is never
   * called for it. 0: written after the run by write_output. */
  int streamed;
} ts_engine_output;

/* An input the engine reads itself, by regions (input_by_regions): run
 * and check get, as in[k], the `img` member of one of these - its width
 * and height, pixels and meta NULL - and reach the
 * path with ts_engine_file_of. Decoded inputs come in one too (callers
 * keep one array), img then holding the pixels. */
typedef struct {
  ts_image img; /* first: in[k] points here */
  char path[4096];
} ts_engine_file;

static inline const ts_engine_file *ts_engine_file_of(const ts_image *img) {
  return (const ts_engine_file *)(const void *)img;
}

/* The input images of a job, in the order run and check receive them.
 * Names are 1..31 lower-case letters, digits and '_' (they name files in
 * the spool); input 0 is the one every job has (mrf: "ref"). */
typedef struct {
  int n;
  char name[TS_ENGINE_MAX_INPUTS][TS_ENGINE_KEY_LEN];
} ts_engine_inputs;

/* Which outputs a job wants: per output of the engine, the extension
 * (IMAGE) or "1" (FLAG); "" = not wanted. Output 0 is the result, always
 * wanted, with the spec key "output" (the CLI's -o): an image, or a FLAG
 * output for an engine whose result is a file of its own (energy.json). */
typedef struct {
  char want[TS_ENGINE_MAX_OUTPUTS][TS_EXT_LEN];
} ts_engine_wants;

/* Checkpoints as bytes: the engine encodes its state after a unit of work
 * (a level), and inside one every checkpoint_interval seconds, and hands
 * it to `save`; `resume` holds the bytes of the last one saved, or NULL.
 * `tag` ties checkpoints to the job's spec (a checkpoint with another tag
 * is refused). */
typedef struct {
  ts_progress_fn *progress; /* may be NULL */
  void *progress_ctx;
  int (*save)(void *ctx, const uint8_t *buf, size_t len, const char *what, char *err); /* may be NULL */
  void *save_ctx;
  double checkpoint_interval; /* 0: after whole units only */
  const uint8_t *resume;
  size_t resume_len;
  uint64_t tag;
  /* Called when `resume` was refused (damaged, foreign, an older format):
   * the job starts over, which gives the same bytes, only later. May be
   * NULL. */
  void (*resume_refused)(void *ctx, const char *why);
  /* Called when the engine resumed from `resume`: where it goes on, and at
   * most how many seconds of the interrupted run's work it does again. */
  void (*resumed)(void *ctx, const char *where, double redone);
  /* Set (by another thread) to stop the run at the end of the step under
   * way, with a checkpoint saved there: the run returns TS_ESTOPPED. A
   * daemon shutting down sets it. NULL: never. */
  const atomic_int *stop;
  /* Where each streamed output goes (ts_engine_output.streamed), by
   * output index; NULL (the array or an entry): not wanted. */
  const char *const *output_paths;
  /* Where an engine that streams a large result keeps a small picture of
   * it, growing as it goes (preview.h): what the operations page shows of
   * a running job, and its thumbnail once done. NULL: none (embedded). */
  const char *preview_path;
  /* Checkpoints in pieces, for work made of many units each finished for
   * good (a tiled scene's tiles): save_piece keeps one under its name
   * (1..31 letters, digits, '-'), atomically, beside the job until it
   * ends; load_piece gives back (malloc'd) one an earlier run of the job
   * saved, or TS_ENOENT. Both with save_ctx; NULL: no pieces (embedded
   * runs). Pieces carry their own checks: the engine refuses one that is
   * damaged or foreign and makes that unit again. */
  int (*save_piece)(void *ctx, const char *name, const uint8_t *buf, size_t len, char *err);
  int (*load_piece)(void *ctx, const char *name, uint8_t **buf, size_t *len, char *err);
} ts_engine_hooks;

typedef struct ts_engine_run ts_engine_run;

typedef struct ts_engine {
  const char *name;  /* the spec's engine= value */
  const ts_engine_output *outputs; /* noutputs entries, [0] the result */
  int noutputs;
  /* Its parameters, declared once (param.h): what the CLI offers, --help
   * and the manual show, and the spec keys spec_set and spec_format take. */
  const ts_param *params;
  void (*params_default)(void *params);
  /* Sets one spec key: 0, TS_EINVAL for a bad value, TS_ENOENT for a key
   * it does not know (outputs are not its business: the spec parser
   * handles them). */
  int (*spec_set)(void *params, const char *key, const char *value);
  /* After parsing: 0, or TS_EINVAL naming a key that has no default and
   * was not given (a spec must survive format and parse). */
  int (*spec_complete)(const void *params, char *err);
  /* Appends its keys as `key=value\n` lines; the length, or TS_ETOOBIG. */
  int (*spec_format)(const void *params, char *buf, size_t cap);
  /* The inputs a job with these parameters takes. */
  void (*inputs)(const void *params, ts_engine_inputs *out);
  /* Optional (NULL: every input decoded whole): 1 if the engine reads
   * input k itself, by regions (ts_engine_file), not decoded by the
   * caller; no pixel limit applies to such an input (see
   * ts_engine_input_read). */
  int (*input_by_regions)(const void *params, int k);
  /* Optional (NULL: none): 1 if input k is a file in no image format that
   * the engine opens itself (a vector layer, a JSON document): neither
   * probed nor decoded; run and check get its path as a ts_engine_file of
   * width and height 0. */
  int (*input_is_file)(const void *params, int k);
  /* Checks parameters against the inputs (in[k] is input k of `inputs`):
   * 0, or TS_EINVAL with every problem listed in msg, one per line. */
  int (*check)(const void *params, const ts_image *const *in, char *msg, size_t len);
  /* Applies a daemon's pixel limit to the parameters. */
  void (*set_max_pixels)(void *params, uint64_t max_pixels);
  /* Bytes the wanted outputs and the checkpoints may take (the spool's
   * disk reserve), given the inputs' headers (in[k] is input k's). */
  uint64_t (*result_bytes)(const void *params, const ts_engine_wants *w, const ts_image_info *in);
  /* Pyramid levels the job goes through (for its status). */
  int (*levels)(const void *params);
  /* Runs the job on its inputs (alive until run_free): *out is the run's
   * state, results included, to write outputs from and free with run_free
   * (on failure too). */
  int (*run)(const void *params, const ts_image *const *in, ts_search *search, const ts_engine_hooks *hooks,
             ts_engine_run **out, char *err);
  /* Writes output k of a finished run to path (threads: for the report). */
  int (*write_output)(const ts_engine_run *run, int k, const char *path, int threads, char *err);
  void (*run_free)(ts_engine_run *run);
} ts_engine;

/* The engine of that name, or NULL. */
const ts_engine *ts_engine_find(const char *name);
/* The i-th engine of the registry (0, 1, ...), or NULL past the last. */
const ts_engine *ts_engine_at(int i);
/* The engine a spec without an `engine` key means (specs spooled before
 * engines had names are MRF jobs). */
const ts_engine *ts_engine_default(void);
/* Index of the output whose spec key is `key`, or -1. */
int ts_engine_output_index(const ts_engine *e, const char *key);
/* The output a fetched file name is ("copymap.png": the one with key
 * "copy_map"), in whichever engine makes it, or NULL. Engines that make
 * the same file give it the same key and kind, so a client can place a
 * job's files without knowing its engine. */
const ts_engine_output *ts_engine_output_of_file(const char *name);
/* The spool file name of output k as wanted ("out.png", "report.json"). */
void ts_engine_output_file(const ts_engine *e, int k, const ts_engine_wants *w, char *out, size_t cap);
/* Whether the engine reads input k of a job with these parameters by
 * regions. */
int ts_engine_input_by_regions(const ts_engine *e, const void *params, int k);
/* Whether input k of a job with these parameters is a file the engine
 * opens itself, of no image format. */
int ts_engine_input_is_file(const ts_engine *e, const void *params, int k);
/* Input k of a job from path into f, as run and check take it: decoded
 * whole within limits, or, for an input read by regions, its header only
 * (no pixel limit: the engine's own limits apply). 0 or an error naming the
 * file; f is freed with ts_image_free(&f->img) either way. */
int ts_engine_input_read(const ts_engine *e, const void *params, int k, const char *path,
                         const ts_image_limits *limits, ts_engine_file *f, char *err);

#endif
