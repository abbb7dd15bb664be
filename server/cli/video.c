/* video.c - `texsyn video`'s options, the checks made before any work,
 * the input (frames, or a movie decoded into the work directory), the
 * work directory, and the report. video_chain.h does the stylizing (and
 * goes on where a run with the same --write-guides DIR stopped);
 * video_flow.h, video_mask.h and video_preview.h the given flows, masks
 * and GIF; video_blend.h puts the sequence together from the chains:
 * between two keys the two chains merged by their piled-up error and
 * blended in the gradient domain; before the first key and after the last
 * the nearest key's chain alone. */
#include "video.h"

#include <dirent.h>
#include <errno.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/stat.h>
#include <unistd.h>

#include "error.h"
#include "flow.h"
#include "image.h"
#include "paramopt.h"
#include "util.h"
#include "video_blend.h"
#include "video_chain.h"
#include "video_flow.h"
#include "video_mask.h"
#include "video_preview.h"

static void usage(FILE *f, const ts_engine *e) {
  fprintf(f,
          "usage: texsyn video --input PATTERN --frames A..B --key N KEY_IMG [--key M KEY_IMG ...]\n"
          "                    -o PATTERN [--pass PATTERN [--weight W]] [options]\n"
          "\n"
          "Stylizes a sequence from painted keyframes (after Jamriska et al. 2019): each\n"
          "frame is a stylize job with the key's painting as exemplar, guided by the\n"
          "frame's colours and edges, by where its content was in the key (the key's pixel\n"
          "coordinates carried along the optical flow) and by the previous stylized frame\n"
          "warped along the flow. From each key a chain of such jobs runs forward to the\n"
          "next key and backward to the previous; between two keys each pixel comes from\n"
          "the chain with the least error piled up along the flow, blended in the\n"
          "gradient domain (no seam, no ghost). Exact and deterministic: the same bytes\n"
          "in-process and on any pool.\n"
          "\n"
          "  --input PATTERN      the input frames, the frame number as %%d or %%04d; one size\n"
          "                       and channel count, at least %dx%d. Or a movie (FFmpeg):\n"
          "                       --frames then counts its frames from 0\n"
          "  --frames A..B        the frames to stylize (0..%d)\n"
          "  --key N KEY_IMG      frame N painted (within A..B, the frames' size); 1..%d keys,\n"
          "                       all with one channel count, which the output has (8-bit)\n"
          "  -o PATTERN           the stylized frames (a key's own frame is its painting)\n"
          "  --pass PATTERN       another guide per frame (render passes, masks): its source\n"
          "                       is the pass at the key's frame; at most %d\n"
          "  --weight W           the weight of the --input or --pass just before it: 0 or\n"
          "                       0.01..100 (default 1)\n"
          "  --mask PATTERN       per frame, where to stylize: white stylized, black the\n"
          "                       input frame as it is, grey between; colour masks by\n"
          "                       their luminance. Also a guide (--mask-weight)\n"
          "  --flow PATTERN       motion vectors per frame instead of computed flow: float\n"
          "                       images (EXR), the first two channels x, y in pixels;\n"
          "                       frame t's maps t to t+1 (content at p moves to p + flow)\n"
          "  --flow-back PATTERN  with --flow, frame t's maps t to t-1 (else --flow inverted)\n"
          "  --preview OUT.gif    the output frames also as an animated GIF (the movie's\n"
          "                       frame rate, else 24 frames a second)\n"
          "  --write-guides DIR   keep the guides made (edges, positions, temporal, each\n"
          "                       chain's frames) in DIR, made if missing; the same\n"
          "                       command again goes on at each chain's next unfinished\n"
          "                       frame\n"
          "  --report F           one JSON object: the settings and every job's report\n",
          TS_FLOW_MIN_SIDE, TS_FLOW_MIN_SIDE, TS_FRAME_LAST, TS_VIDEO_MAX_KEYS, TS_VIDEO_MAX_PASSES);
  ts_params_help(f, ts_video_params, NULL);
  ts_params_help(f, e->params, ts_video_defaults);
  fprintf(f, "%s  (not --detach: each frame needs the one before, so the command follows its jobs)\n",
          TS_JOB_RUN_HELP);
}

/* The command's own options; its guides' weights follow from
 * ts_video_params (video_guides.h), OPT_WEIGHTS + their index. */
enum { OPT_INPUT = TS_OPT_OWN, OPT_FRAMES, OPT_KEY, OPT_PASS, OPT_WEIGHT, OPT_GUIDES, OPT_MASK, OPT_FLOW, OPT_FLOW_BACK,
       OPT_PREVIEW, OPT_WEIGHTS };

static const struct option fixed_opts[] = {
    {"input", required_argument, 0, OPT_INPUT},   {"frames", required_argument, 0, OPT_FRAMES},
    {"key", required_argument, 0, OPT_KEY},       {"pass", required_argument, 0, OPT_PASS},
    {"weight", required_argument, 0, OPT_WEIGHT}, {"write-guides", required_argument, 0, OPT_GUIDES},
    {"mask", required_argument, 0, OPT_MASK},     {"flow", required_argument, 0, OPT_FLOW},
    {"flow-back", required_argument, 0, OPT_FLOW_BACK}, {"preview", required_argument, 0, OPT_PREVIEW},
    TS_JOB_LONGOPTS,
    {0, 0, 0, 0}};

typedef struct {
  ts_video v;
  int weighs; /* what --weight sets: -1 nothing yet, 0 the input, p + 1 pass p */
  const char *frames, *report;
  const char *movie;                    /* --input a movie: its path (v.input: its frames decoded) */
  double fps;                           /* the movie's, for --preview (0: not a movie, or it does not say) */
  const char *preview;                  /* --preview OUT.gif or NULL */
  char movie_frames[TS_VIDEO_PATH + 32]; /* where they are decoded to, in the work directory */
} video_opts;

/* fixed_opts, then one option per entry of ts_video_params: 0, or
 * TS_ETOOBIG when they do not fit in cap entries. */
static int own_options(struct option *out, size_t cap) {
  size_t n = 0;
  for (; fixed_opts[n].name != NULL; n++) out[n] = fixed_opts[n];
  for (int i = 0; ts_video_params[i].key != NULL; i++) {
    if (n + 1 >= cap) return TS_ETOOBIG;
    out[n++] = (struct option){ts_video_params[i].flag, required_argument, 0, OPT_WEIGHTS + i};
  }
  out[n] = (struct option){0, 0, 0, 0};
  return 0;
}

/* --key N KEY_IMG: getopt hands over N; KEY_IMG is the next word. */
static int key_option(video_opts *o, int argc, char **argv, const char *n, char *err) {
  if (optind >= argc || (argv[optind][0] == '-' && argv[optind][1] != '\0'))
    return ts_error(err, TS_EINVAL, "--key %s: needs the painted image after the frame number (--key N KEY_IMG)", n);
  if (o->v.nkeys == TS_VIDEO_MAX_KEYS) return ts_error(err, TS_EINVAL, "--key: at most %d keys", TS_VIDEO_MAX_KEYS);
  ts_video_key *k = &o->v.key[o->v.nkeys++];
  k->image = argv[optind++];
  return ts_arg_long("--key", n, 0, TS_FRAME_LAST, &k->frame, err);
}

static int pass_option(video_opts *o, const char *arg, char *err) {
  if (o->v.npass == TS_VIDEO_MAX_PASSES)
    return ts_error(err, TS_EINVAL, "--pass: at most %d passes", TS_VIDEO_MAX_PASSES);
  o->v.pass_weight[o->v.npass] = 1;
  o->v.pass[o->v.npass++] = arg;
  o->weighs = o->v.npass;
  return 0;
}

/* --weight W: 0 or 0.01..100, as stylize's --weight. */
static int weight_option(video_opts *o, const char *arg, char *err) {
  if (o->weighs < 0) return ts_error(err, TS_EINVAL, "--weight %s: put it after the --input or --pass it weighs", arg);
  double *w = o->weighs == 0 ? &o->v.input_weight : &o->v.pass_weight[o->weighs - 1];
  int rc = ts_arg_double("--weight", arg, w, err);
  if (rc == 0 && *w != 0 && (*w < 0.01 || *w > 100))
    rc = ts_error(err, TS_EINVAL, "--weight %s: need 0 or 0.01..100", arg);
  return rc;
}

/* A guide's weight (ts_video_params); its range is checked after the
 * loop, as an engine parameter's is. */
static int weights_option(video_opts *o, int i, const char *arg, char *err) {
  char what[64];
  snprintf(what, sizeof(what), "--%s", ts_video_params[i].flag);
  return ts_param_parse(&ts_video_params[i], &o->v.wt, arg, what, err);
}

/* The command's own options (ts_cmd_options.option): TS_ENOENT for the
 * engine's and every job's. */
static int video_option(void *ctx, int c, const char *arg, int argc, char **argv, char *err) {
  video_opts *o = ctx;
  ts_video *v = &o->v;
  if (c >= OPT_WEIGHTS && c < OPT_WEIGHTS + ts_param_count(ts_video_params))
    return weights_option(o, c - OPT_WEIGHTS, arg, err);
  if (c >= TS_OPT_SIDE) /* stylize's side outputs (--nnf): one file, which every frame would overwrite */
    return ts_error(err, TS_EINVAL, "--%s: a stylize side output is one file, which every frame would overwrite: "
                    "texsyn video does not take it", v->job.spec.engine->outputs[c - TS_OPT_SIDE].flag);
  switch (c) {
  case OPT_INPUT: v->input = arg; o->weighs = 0; return 0;
  case OPT_FRAMES: o->frames = arg; return ts_frames_parse(arg, &v->fr, err);
  case OPT_KEY: return key_option(o, argc, argv, arg, err);
  case OPT_PASS: return pass_option(o, arg, err);
  case OPT_WEIGHT: return weight_option(o, arg, err);
  case OPT_GUIDES: v->guides_dir = arg; return 0;
  case OPT_MASK: v->mask = arg; return 0;
  case OPT_FLOW: v->flow = arg; return 0;
  case OPT_FLOW_BACK: v->flow_back = arg; return 0;
  case OPT_PREVIEW: o->preview = arg; return 0;
  case TS_OPT_REPORT: o->report = arg; return TS_ENOENT; /* noted, then taken as every job's --report */
  case TS_OPT_DETACH: return ts_error(err, TS_EINVAL, "--detach: each frame needs the one before, so texsyn video "
                                      "follows its jobs to the end");
  default: return TS_ENOENT;
  }
}

static int key_order(const void *a, const void *b) {
  long x = ((const ts_video_key *)a)->frame, y = ((const ts_video_key *)b)->frame;
  return x < y ? -1 : x > y;
}

/* What must be there after the options; the keys sorted. */
static int parse_end(video_opts *o, char *err) {
  ts_video *v = &o->v;
  if (v->input == NULL || o->frames == NULL || v->nkeys == 0)
    return ts_error(err, TS_EINVAL, "--input PATTERN, --frames A..B and at least one --key N KEY_IMG are required "
                    "(see texsyn video --help)");
  char msg[1024] = "";
  int problems = 0;
  ts_params_check(ts_video_params, &v->wt, msg, sizeof(msg), &problems);
  if (problems > 0) return ts_error(err, TS_EINVAL, "%s", msg);
  if (v->flow_back != NULL && v->flow == NULL)
    return ts_error(err, TS_EINVAL, "--flow-back %s: give --flow too (the flow towards the next frame)", v->flow_back);
  if (v->mask != NULL && v->wt.mask > 0 && v->npass == TS_VIDEO_MAX_PASSES)
    return ts_error(err, TS_EINVAL, "--mask takes a guide: at most %d --pass with it", TS_VIDEO_MAX_PASSES - 1);
  qsort(v->key, (size_t)v->nkeys, sizeof(v->key[0]), key_order);
  for (int k = 0; k < v->nkeys; k++) {
    if (v->key[k].frame < v->fr.first || v->key[k].frame > v->fr.last)
      return ts_error(err, TS_EINVAL, "--key %ld %s: frame %ld is outside --frames %s", v->key[k].frame,
                      v->key[k].image, v->key[k].frame, o->frames);
    if (k > 0 && v->key[k].frame == v->key[k - 1].frame)
      return ts_error(err, TS_EINVAL, "--key %ld: given twice (%s and %s)", v->key[k].frame, v->key[k - 1].image,
                      v->key[k].image);
  }
  if (ts_paramopt_number(&v->job, "scale") != 1)
    return ts_error(err, TS_EINVAL, "--scale: texsyn video works at the frames' size (scale the frames and keys "
                    "first for a preview)");
  int rc = ts_job_parse_end(&v->job, err);
  if (rc == 0) rc = ts_paramopt_check(&v->job, err);
  v->out = ts_output_path(&v->job.out, "output");
  return rc == 0 ? ts_video_weigh(v, err) : rc;
}

/* '+': no reordering of argv, so the word after --key N is its image. */
static int video_parse(int argc, char **argv, video_opts *o, char *err) {
  memset(o, 0, sizeof(*o));
  ts_job_cmd_init(&o->v.job, "video", ts_engine_find("stylize"));
  o->weighs = -1;
  o->v.input_weight = 1;
  ts_params_default(ts_video_params, &o->v.wt);
  struct option own[TS_PARAMOPT_MAX];
  if (own_options(own, TS_PARAMOPT_MAX) != 0) return ts_error(err, TS_EINVAL, "internal: too many options");
  ts_cmd_options cmd = {"+o:h", own, video_option, usage, ts_video_defaults};
  int rc = ts_paramopt_parse(&o->v.job, &cmd, o, argc, argv, err);
  return rc != 0 ? rc : parse_end(o, err);
}

/* ---- before any work ------------------------------------------------- */

/* The header of path (what names it in a message). */
static int probe(const char *what, const char *path, const ts_video *v, ts_image_info *info, char *err) {
  uint8_t *buf = NULL;
  size_t len = 0;
  ts_image_limits limits = {v->job.max_pixels, NULL};
  int rc = ts_file_read(path, 1ull << 32, &buf, &len, err);
  if (rc == 0) rc = ts_image_probe_mem(path, buf, len, &limits, info, err);
  free(buf);
  if (rc != 0) {
    char why[TS_ERR_LEN];
    snprintf(why, sizeof(why), "%s", err);
    return ts_error(err, rc, "%s: %s (nothing was stylized)", what, why);
  }
  return 0;
}

/* Every frame of a sequence readable, of one size and channel count; the
 * first frame's header in *first. */
static int check_sequence(const char *option, const char *pattern, const ts_video *v, ts_image_info *first,
                          char *err) {
  int n = ts_frame_pattern(pattern, err);
  if (n < 0) return n;
  if (n == 0)
    return ts_error(err, TS_EINVAL, "%s %s: put the frame number in the name (%%d or %%04d, e.g. shot/%%04d.png)",
                    option, pattern);
  char path[TS_VIDEO_PATH], what[64];
  for (long f = v->fr.first; f <= v->fr.last; f++) {
    ts_image_info info;
    if (ts_frame_path(pattern, f, path, sizeof(path)) != 0) return ts_error(err, TS_EINVAL, "%s: path too long", pattern);
    snprintf(what, sizeof(what), "%s frame %ld", option, f);
    int rc = probe(what, path, v, f == v->fr.first ? first : &info, err);
    if (rc != 0) return rc;
    if (f > v->fr.first && (info.width != first->width || info.height != first->height ||
                            info.channels != first->channels))
      return ts_error(err, TS_EINVAL, "%s frame %ld (%s) is %dx%d with %d channels, frame %ld %dx%d with %d: every "
                      "frame must have the first one's size and channels", option, f, path, info.width, info.height,
                      info.channels, v->fr.first, first->width, first->height, first->channels);
  }
  return 0;
}

/* The keys: readable, the frames' size, one channel count (v->channels). */
static int check_keys(ts_video *v, char *err) {
  for (int k = 0; k < v->nkeys; k++) {
    ts_image_info info;
    char what[64];
    snprintf(what, sizeof(what), "--key %ld", v->key[k].frame);
    int rc = probe(what, v->key[k].image, v, &info, err);
    if (rc != 0) return rc;
    if (info.width != v->w || info.height != v->h)
      return ts_error(err, TS_EINVAL, "--key %ld %s is %dx%d, the frames %dx%d: a key is a painted frame, of the "
                      "frames' size", v->key[k].frame, v->key[k].image, info.width, info.height, v->w, v->h);
    if (k > 0 && info.channels != v->channels)
      return ts_error(err, TS_EINVAL, "--key %ld %s has %d channels, but --key %ld %s has %d: every key needs the same "
                      "count (the output's)", v->key[k].frame, v->key[k].image, info.channels, v->key[0].frame,
                      v->key[0].image, v->channels);
    v->channels = info.channels;
  }
  return 0;
}

/* Every output frame writable. */
static int check_outputs(const ts_video *v, char *err) {
  int n = ts_frame_pattern(v->out, err);
  if (n < 0) return n;
  if (n == 0)
    return ts_error(err, TS_EINVAL, "-o %s: put the frame number in the name (%%04d: out_%%04d.png), or every frame "
                    "would overwrite it", v->out);
  ts_job_cmd job = v->job;
  char path[TS_VIDEO_PATH];
  job.out = (ts_output_paths){0};
  ts_output_set(&job.out, "output", path);
  for (long f = v->fr.first; f <= v->fr.last; f++) {
    if (ts_frame_path(v->out, f, path, sizeof(path)) != 0) return ts_error(err, TS_EINVAL, "%s: path too long", v->out);
    int rc = ts_job_check_outputs(&job, err);
    if (rc != 0) return rc;
  }
  return 0;
}

/* --input without a frame number: a movie, whose frames A..B are there
 * (frame 0 its first); its frames' header in *first. */
static int check_movie(video_opts *o, ts_image_info *first, char *err) {
  ts_video *v = &o->v;
  ts_movie_info mi;
  ts_image_limits limits = {v->job.max_pixels, NULL};
  int rc = ts_movie_probe(v->input, &limits, &mi, err);
  if (rc != 0) {
    char why[TS_ERR_LEN];
    snprintf(why, sizeof(why), "%s", err);
    return ts_error(err, rc, "--input: %s; nothing was stylized (a sequence of images needs the frame number in "
                    "the name: %%d or %%04d, e.g. shot/%%04d.png)", why);
  }
  if (mi.frames == 1)
    return ts_error(err, TS_EINVAL, "--input %s: one image; put the frame number in the name (%%d or %%04d, e.g. "
                    "shot/%%04d.png) or give a movie", v->input);
  if (v->fr.last >= mi.frames)
    return ts_error(err, TS_EINVAL, "--frames %s: the movie %s has %d frames, 0..%d", o->frames, v->input, mi.frames,
                    mi.frames - 1);
  *first = mi.frame;
  o->movie = v->input;
  o->fps = mi.fps;
  return 0;
}

/* The --input sequence or movie: one size and channel count, *first. */
static int check_input(video_opts *o, ts_image_info *first, char *err) {
  int n = ts_frame_pattern(o->v.input, err);
  if (n < 0) return n;
  return n == 0 ? check_movie(o, first, err) : check_sequence("--input", o->v.input, &o->v, first, err);
}

/* --preview: a .gif, writable. */
static int check_preview(const video_opts *o, char *err) {
  size_t n = strlen(o->preview);
  if (n < 4 || strcasecmp(o->preview + n - 4, ".gif") != 0)
    return ts_error(err, TS_EINVAL, "--preview %s: an animated GIF, named .gif", o->preview);
  ts_job_cmd job = o->v.job;
  job.out = (ts_output_paths){0};
  ts_output_set(&job.out, "output", o->preview);
  return ts_job_check_outputs(&job, err);
}

static int check_all(video_opts *o, char *err) {
  ts_video *v = &o->v;
  ts_image_info first;
  int rc = v->flow == NULL ? ts_flow_lib_load(err) : 0; /* given flows need no OpenCV */
  if (rc == 0) rc = check_input(o, &first, err);
  if (rc != 0) return rc;
  v->w = first.width;
  v->h = first.height;
  if (v->w < TS_FLOW_MIN_SIDE || v->h < TS_FLOW_MIN_SIDE)
    return ts_error(err, TS_EINVAL, "--input frames are %dx%d: the optical flow needs at least %dx%d", v->w, v->h,
                    TS_FLOW_MIN_SIDE, TS_FLOW_MIN_SIDE);
  rc = check_keys(v, err);
  for (int p = 0; rc == 0 && p < v->npass; p++) {
    rc = check_sequence("--pass", v->pass[p], v, &first, err);
    if (rc == 0 && (first.width != v->w || first.height != v->h))
      rc = ts_error(err, TS_EINVAL, "--pass %s: its frames are %dx%d, the input's %dx%d", v->pass[p], first.width,
                    first.height, v->w, v->h);
  }
  if (rc == 0 && v->mask != NULL) {
    rc = check_sequence("--mask", v->mask, v, &first, err);
    if (rc == 0 && (first.width != v->w || first.height != v->h))
      rc = ts_error(err, TS_EINVAL, "--mask %s: its frames are %dx%d, the input's %dx%d", v->mask, first.width,
                    first.height, v->w, v->h);
  }
  if (rc == 0) rc = ts_video_flow_check(v, err);
  if (rc == 0) rc = check_outputs(v, err);
  if (rc == 0 && o->preview != NULL) rc = check_preview(o, err);
  if (rc == 0 && o->report != NULL) {
    ts_job_cmd job = v->job;
    job.out = (ts_output_paths){0};
    ts_output_set(&job.out, "report", o->report);
    rc = ts_job_check_outputs(&job, err);
  }
  return rc;
}

/* ---- the movie's frames ------------------------------------------------ */

static int movie_frame(void *ctx, long frame, const ts_image *img, char *err) {
  char path[TS_VIDEO_PATH + 64];
  ts_frame_path(ctx, frame, path, sizeof(path)); /* fits: the work directory's */
  return ts_image_write(path, img, NULL, err);
}

/* --input a movie: its frames A..B decoded into the work directory as
 * lossless PNGs, which then are the input sequence. */
static int movie_decode(video_opts *o, const char *dir, char *err) {
  snprintf(o->movie_frames, sizeof(o->movie_frames), "%s/input_%%04d.png", dir);
  ts_image_limits limits = {o->v.job.max_pixels, NULL};
  int rc = ts_movie_read(o->movie, o->v.fr.first, o->v.fr.last, &limits, movie_frame, o->movie_frames, err);
  o->v.input = o->movie_frames;
  return rc;
}

/* ---- the work directory ------------------------------------------------ */

/* --write-guides DIR (made if missing), else a temporary directory. */
static int workdir_make(const ts_video *v, char *dir, size_t cap, char *err) {
  if (v->guides_dir != NULL) {
    snprintf(dir, cap, "%s", v->guides_dir);
    if (mkdir(dir, 0777) != 0 && errno != EEXIST)
      return ts_error(err, TS_EIO, "--write-guides %s: cannot make it: %s", dir, strerror(errno));
    return 0;
  }
  const char *tmp = getenv("TMPDIR");
  snprintf(dir, cap, "%s/texsyn-video-XXXXXX", tmp != NULL && tmp[0] != '\0' ? tmp : "/tmp");
  if (mkdtemp(dir) == NULL)
    return ts_error(err, TS_EIO, "cannot make a work directory %s: %s (set TMPDIR to a writable directory)", dir,
                    strerror(errno));
  return 0;
}

/* The temporary work directory removed (it holds only files). */
static void workdir_remove(const char *dir) {
  DIR *d = opendir(dir);
  struct dirent *e;
  char path[TS_VIDEO_PATH + 256];
  while (d != NULL && (e = readdir(d)) != NULL) {
    if (strcmp(e->d_name, ".") == 0 || strcmp(e->d_name, "..") == 0) continue;
    snprintf(path, sizeof(path), "%s/%s", dir, e->d_name);
    unlink(path);
  }
  if (d != NULL) closedir(d);
  rmdir(dir);
}

/* ---- the sequence ------------------------------------------------------ */

/* The sequence written (video_blend.h); with --mask first into dir, then
 * composited into the outputs (video_mask.h). */
static int sequence_out(ts_video *v, const char *dir, ts_video_blend *b, char *err) {
  if (v->mask == NULL) return ts_video_blend_write(v, dir, b, err);
  const char *out = v->out;
  char stylized[TS_VIDEO_PATH + 32];
  snprintf(stylized, sizeof(stylized), "%s/stylized_%%04d.png", dir);
  v->out = stylized;
  int rc = ts_video_blend_write(v, dir, b, err);
  v->out = out;
  return rc == 0 ? ts_video_mask_write(v, dir, stylized, err) : rc;
}

/* ---- on a coordinator -------------------------------------------------- */

/* What every job says of the sequence (video_chain.h): the id is the
 * hash of the work, so a rerun that goes on where one stopped shows as
 * the same sequence on the operations page. */
static void sequence_tag(ts_video *v, uint64_t hash) {
  ts_jobspec_seq *q = &v->seq;
  snprintf(q->id, sizeof(q->id), "%016" PRIx64, hash);
  ts_jobspec_name_of(v->out, q->name, sizeof(q->name));
  q->first = v->fr.first;
  q->last = v->fr.last;
  q->jobs = ts_video_job_count(v);
}

/* ---- the report ------------------------------------------------------ */

/* Appends the file at path to f as it is (a job's JSON report). */
static int append_file(FILE *f, const char *path, char *err) {
  uint8_t *buf = NULL;
  size_t len = 0;
  int rc = ts_file_read(path, 1u << 26, &buf, &len, err);
  while (rc == 0 && len > 0 && (buf[len - 1] == '\n' || buf[len - 1] == ' ')) len--;
  if (rc == 0) fwrite(buf, 1, len, f);
  free(buf);
  return rc;
}

/* One JSON object: the sequence, keys, weights, the flow, and each job's
 * report in chain order. */
static int write_report(const ts_video *v, const char *dir, const ts_video_blend *b, const char *path, char *err) {
  FILE *f = fopen(path, "w");
  if (f == NULL) return ts_error(err, TS_EIO, "cannot write %s: %s", path, strerror(errno));
  fprintf(f, "{\"frames\": [%ld, %ld], \"size\": [%d, %d], \"flow\": \"%s\", \"weights\": {\"input\": %g, "
          "\"edge\": %g, \"position\": %g, \"temporal\": %g, \"mask\": %g}, \"blend\": ",
          v->fr.first, v->fr.last, v->w, v->h,
          v->flow == NULL ? ts_flow_method() : v->flow_back == NULL ? "given (--flow; backward: inverted)"
                                                                   : "given (--flow, --flow-back)", v->input_weight, v->wt.edge,
          v->wt.position, v->wt.temporal, v->mask != NULL ? v->wt.mask : 0);
  ts_video_blend_json(f, b);
  fprintf(f, ", \"keys\": [");
  for (int k = 0; k < v->nkeys; k++) fprintf(f, "%s%ld", k ? ", " : "", v->key[k].frame);
  fprintf(f, "], \"jobs\": [");
  int rc = 0, first = 1;
  char file[TS_VIDEO_PATH];
  for (long t = v->fr.first; rc == 0 && t <= v->fr.last; t++)
    for (int k = 0; rc == 0 && k < v->nkeys; k++) {
      ts_video_chain_file(dir, v->key[k].frame, t, "report.json", file, sizeof(file));
      if (access(file, R_OK) != 0) continue;
      fprintf(f, "%s\n  {\"frame\": %ld, \"key\": %ld, \"report\": ", first ? "" : ",", t, v->key[k].frame);
      rc = append_file(f, file, err);
      fprintf(f, "}");
      first = 0;
    }
  fprintf(f, "]}\n");
  if (fclose(f) != 0 && rc == 0) rc = ts_error(err, TS_EIO, "cannot write %s: %s", path, strerror(errno));
  return rc;
}

int ts_cmd_video(int argc, char **argv) {
  char err[TS_ERR_LEN] = "", dir[TS_VIDEO_PATH];
  video_opts *o = calloc(1, sizeof(*o));
  if (o == NULL) {
    fprintf(stderr, "texsyn video: out of memory\n");
    return 1;
  }
  int rc = video_parse(argc, argv, o, err);
  int status = rc == 0 ? 0 : 2;
  if (rc == 0) rc = check_all(o, err);
  if (rc != 0 && status == 0) status = rc == TS_EINVAL ? 2 : 1;
  int made = rc == 0 && (rc = workdir_make(&o->v, dir, sizeof(dir), err)) == 0, resume = 0;
  if (rc == 0 && o->movie != NULL) rc = movie_decode(o, dir, err);
  uint64_t hash = 0;
  if (rc == 0 && (o->v.guides_dir != NULL || o->v.job.server != NULL)) rc = ts_video_hash(&o->v, &hash, err);
  if (rc == 0 && o->v.guides_dir != NULL) rc = ts_video_claim(&o->v, dir, hash, &resume, err);
  if (rc == 0 && o->v.job.server != NULL) sequence_tag(&o->v, hash);
  if (rc == 0) rc = ts_video_prepare(&o->v, dir, err);
  if (rc == TS_EINVAL && status == 0) status = 2;
  if (rc == 0) rc = ts_video_run_chains(&o->v, dir, resume, err);
  ts_video_blend blend = {0};
  if (rc == 0) rc = sequence_out(&o->v, dir, &blend, err);
  if (rc == 0 && o->preview != NULL) rc = ts_video_preview(&o->v, o->preview, o->fps > 0 ? o->fps : 24, err);
  if (rc == 0 && o->report != NULL) rc = write_report(&o->v, dir, &blend, o->report, err);
  ts_video_blend_free(&blend);
  if (made && o->v.guides_dir == NULL) workdir_remove(dir);
  if (rc != 0) fprintf(stderr, "texsyn video: %s\n", err);
  if (rc != 0 && status == 0) status = 1;
  free(o);
  return status;
}
