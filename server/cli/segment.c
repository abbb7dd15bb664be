/* segment.c - `texsyn segment`'s options; the job itself runs through
 * jobcmd.h like every job (in-process, or on a coordinator with --server).
 * Two things are its own: the inputs' headers are checked here first, so
 * that a problem names the file at fault (the engine's own check names
 * inputs by their options: it runs where the paths are unknown), and with
 * --truth the accuracy table the job writes is printed. */
#include "segment.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "../engines/segment.h"
#include "error.h"
#include "image.h"
#include "jobcmd.h"
#include "paramopt.h"
#include "util.h"

static const char *const kUsage =
    "usage: texsyn segment --train IMG --labels LBL [--train IMG --labels LBL ...]\n"
    "                      --input IMG -o LABELS [options]\n"
    "\n"
    "Labels every pixel of IMG with the class of the training pixel whose NxN window\n"
    "looks most like its own (1-NN \"iMRF\" segmentation after Stahlhut 2004, exact L1\n"
    "through the search service), on every pyramid level; the levels are fused with\n"
    "per-class weights from segmenting each half of every training image with the\n"
    "rest, then regions smaller than --denoise pixels join their surroundings.\n"
    "\n"
    "  --train IMG          a training image (any format texsyn reads); 1..%d pairs\n"
    "  --labels LBL         its label raster: one 8- or 16-bit channel, the training\n"
    "                       image's size; every value in it is a class (0 included)\n"
    "  --input IMG          the image to segment\n"
    "  -o, --output LABELS  the label raster out: the input's size, the training label\n"
    "                       values, 16-bit if a label raster is, else 8-bit\n"
    "  --truth TRUTH        the right labels (the input's size, values among the\n"
    "                       classes): print per-class and overall accuracy before and\n"
    "                       after noise reduction; --report records them too\n"
    "  --report F           JSON: parameters, per level sizes, queries, comparisons,\n"
    "                       seconds, self-segmentation rates and weights; accuracy\n";

enum { OPT_TRAIN = TS_OPT_OWN, OPT_LABELS, OPT_INPUT, OPT_TRUTH };

/* Its own options: the inputs (the parameters are the engine's). */
static const struct option own_opts[] = {
    {"train", required_argument, 0, OPT_TRAIN}, {"labels", required_argument, 0, OPT_LABELS},
    {"input", required_argument, 0, OPT_INPUT}, {"truth", required_argument, 0, OPT_TRUTH},
    TS_JOB_LONGOPTS,                            {0, 0, 0, 0}};

typedef struct {
  ts_job_cmd job;
  const char *train[TS_SEG_MAX_PAIRS], *labels[TS_SEG_MAX_PAIRS], *input, *truth;
  int ntrain, nlabels;
  char accuracy[4096]; /* the temporary file the table goes to (mkstemp's template until made) */
} seg_opts;

/* The parameters, read only: the CLI sets them through the spec keys. */
static const ts_seg_params *params(const seg_opts *o) { return (const ts_seg_params *)o->job.spec.params.bytes; }

/* --train and --labels pair up in order: the k-th --labels is the k-th
 * --train's. */
static int pair_option(seg_opts *o, int c, const char *arg, char *err) {
  const char **list = c == OPT_TRAIN ? o->train : o->labels;
  int *n = c == OPT_TRAIN ? &o->ntrain : &o->nlabels;
  if (*n == TS_SEG_MAX_PAIRS)
    return ts_error(err, TS_EINVAL, "%s %s: at most %d training pairs", c == OPT_TRAIN ? "--train" : "--labels", arg,
                    TS_SEG_MAX_PAIRS);
  list[(*n)++] = arg;
  return 0;
}

static int seg_option(void *ctx, int c, const char *arg, int argc, char **argv, char *err) {
  (void)argc, (void)argv;
  seg_opts *o = ctx;
  switch (c) {
  case OPT_TRAIN: case OPT_LABELS: return pair_option(o, c, arg, err);
  case OPT_INPUT: o->input = arg; return 0;
  case OPT_TRUTH: o->truth = arg; return 0;
  default: return TS_ENOENT;
  }
}

static void usage(FILE *f, const ts_engine *e) {
  fprintf(f, kUsage, TS_SEG_MAX_PAIRS);
  ts_paramopt_help(f, e);
  fprintf(f, "%s", TS_JOB_RUN_HELP);
}

/* The pairs complete, and the inputs in the engine's order. */
static int inputs_complete(seg_opts *o, char *err) {
  if (o->ntrain == 0) return ts_error(err, TS_EINVAL, "at least one --train IMG --labels LBL is required");
  if (o->nlabels < o->ntrain)
    return ts_error(err, TS_EINVAL, "--train %s has no --labels: give a --labels LBL for each --train IMG, in order",
                    o->train[o->nlabels]);
  if (o->nlabels > o->ntrain)
    return ts_error(err, TS_EINVAL, "--labels %s has no --train: give a --train IMG for each --labels LBL, in order",
                    o->labels[o->ntrain]);
  if (o->input == NULL) return ts_error(err, TS_EINVAL, "--input IMG is required (see texsyn segment --help)");
  char pairs[16];
  snprintf(pairs, sizeof(pairs), "%d", o->ntrain);
  if (ts_job_set_key(&o->job, "pairs", pairs, "--train", err) != 0 ||
      ts_job_set_key(&o->job, "truth", o->truth != NULL ? "1" : "0", "--truth", err) != 0)
    return TS_EINVAL;
  const ts_seg_params *p = params(o);
  o->job.in[TS_SEG_IN_INPUT] = o->input;
  for (int k = 0; k < o->ntrain; k++) {
    o->job.in[ts_seg_in_train(k)] = o->train[k];
    o->job.in[ts_seg_in_labels(k)] = o->labels[k];
  }
  if (o->truth != NULL) o->job.in[ts_seg_in_truth(p)] = o->truth;
  return 0;
}

static int seg_parse(int argc, char **argv, seg_opts *o, char *err) {
  memset(o, 0, sizeof(*o));
  ts_job_cmd_init(&o->job, "segment", ts_engine_find("segment"));
  static const ts_cmd_options cmd = {"o:h", own_opts, seg_option, usage};
  int rc = ts_paramopt_parse(&o->job, &cmd, o, argc, argv, err);
  if (rc != 0) return rc;
  rc = inputs_complete(o, err);
  return rc != 0 ? rc : ts_job_parse_end(&o->job, err);
}

/* ---- the check by file name ---------------------------------------------- */

/* The header of an input file. */
static int probe(const char *path, uint64_t max_pixels, ts_image_info *info, char *err) {
  uint8_t *data = NULL;
  size_t len = 0;
  ts_image_limits limits = {max_pixels, NULL};
  int rc = ts_file_read(path, SIZE_MAX, &data, &len, err);
  if (rc == 0) rc = ts_image_probe_mem(path, data, len, &limits, info, err);
  free(data);
  return rc;
}

/* The option an input comes from. */
static const char *option_of(const ts_seg_params *p, int k) {
  if (k == TS_SEG_IN_INPUT) return "--input";
  if (p->truth && k == ts_seg_in_truth(p)) return "--truth";
  return k % 2 ? "--train" : "--labels";
}

/* The engine's header check with each input named by its option and
 * path: the exit status so far (0, 1 for an unreadable file, 2 for a
 * problem, every problem listed). */
static int check_files(seg_opts *o) {
  const ts_seg_params *p = params(o);
  ts_image_info info[2 * TS_SEG_MAX_PAIRS + 2];
  char names[2 * TS_SEG_MAX_PAIRS + 2][512];
  const char *np[2 * TS_SEG_MAX_PAIRS + 2];
  char err[TS_ERR_LEN] = "", msg[8192];
  for (int k = 0; k < ts_seg_ninputs(p); k++) {
    snprintf(names[k], sizeof(names[k]), "%s %s", option_of(p, k), o->job.in[k]);
    np[k] = names[k];
    if (probe(o->job.in[k], o->job.max_pixels, &info[k], err) != 0) {
      fprintf(stderr, "texsyn segment: %s\n", err);
      return 1;
    }
  }
  if (ts_seg_check_headers(p, info, np, msg, sizeof(msg)) == 0) return 0;
  fprintf(stderr, "texsyn segment: invalid parameters:\n%s\n", msg);
  return 2;
}

/* ---- the accuracy table -------------------------------------------------- */

/* With --truth (and not detached): the table goes to a temporary file,
 * printed once the job has written it. */
static int accuracy_file(seg_opts *o, char *err) {
  const char *dir = getenv("TMPDIR");
  snprintf(o->accuracy, sizeof(o->accuracy), "%s/texsyn-accuracy-XXXXXX",
           dir != NULL && dir[0] != '\0' ? dir : "/tmp");
  int fd = mkstemp(o->accuracy);
  if (fd < 0)
    return ts_error(err, TS_EIO, "cannot make a temporary file in %s for the accuracy: %s (set TMPDIR to a "
                    "writable directory)", dir != NULL && dir[0] != '\0' ? dir : "/tmp", strerror(errno));
  close(fd);
  ts_output_set(&o->job.out, "accuracy", o->accuracy);
  return 0;
}

static int print_accuracy(const seg_opts *o, char *err) {
  uint8_t *buf = NULL;
  size_t len = 0;
  int rc = ts_file_read(o->accuracy, 65536, &buf, &len, err);
  if (rc == 0) fwrite(buf, 1, len, stdout);
  free(buf);
  return rc;
}

int ts_cmd_segment(int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  seg_opts o;
  if (seg_parse(argc, argv, &o, err) != 0) {
    fprintf(stderr, "texsyn segment: %s\n", err);
    return 2;
  }
  int status = check_files(&o);
  if (status != 0) return status;
  int table = o.truth != NULL && !o.job.detach;
  if (table && accuracy_file(&o, err) != 0) {
    fprintf(stderr, "texsyn segment: %s\n", err);
    return 1;
  }
  status = ts_job_run(&o.job);
  if (table && status == 0 && print_accuracy(&o, err) != 0) {
    fprintf(stderr, "texsyn segment: %s\n", err);
    status = 1;
  }
  if (table) unlink(o.accuracy);
  return status;
}
