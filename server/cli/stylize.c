/* stylize.c - `texsyn stylize`'s options, named after Ebsynth's so its
 * users find their way (-style, -guide SRC TGT, -weight after what it
 * weighs, -patchsize, -pyramidlevels, -searchvoteiters, -uniformity); the
 * job itself runs through jobcmd.h like every job. */
#include "stylize.h"

#include <errno.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "error.h"
#include "frames.h"
#include "jobcmd.h"
#include "paramopt.h"
#include "stylit.h"
#include "util.h"

static void usage(FILE *f, const ts_engine *e) {
  fprintf(f,
          "usage: texsyn stylize --style EXEMPLAR --guide SRC TGT [--weight W] [--guide SRC TGT ...]\n"
          "                      -o OUT [options]\n"
          "\n"
          "Paints the target in the style of EXEMPLAR (StyLit-style guided synthesis, with\n"
          "an occurrence-map uniformity term): each guide pair tells which exemplar region\n"
          "goes where - SRC lies on the exemplar, TGT on the output (render passes,\n"
          "segmentations). Exact: every target patch takes the best source patch (ties to\n"
          "the lowest index), so a job and seed give the same bytes on any machine.\n"
          "\n"
          "  --style IMG          the painted exemplar; the output has its channels, 8-bit,\n"
          "                       at the target guides' size\n"
          "  --guide SRC TGT      a guide pair: SRC the exemplar's size, TGT the output's;\n"
          "                       1..%d pairs; 8/16-bit as is, float (EXR) passes stretched\n"
          "                       per channel over the pair's range\n"
          "  --weight W           the weight of the --style or --guide just before it:\n"
          "                       0 or 0.01..100; the style 1, each of N guides 1/N by\n"
          "                       default (weights count whole images, whatever their channels)\n"
          "  --frames A..B        a sequence: frames A to B (0..%d, at most %d), each\n"
          "                       a job on the files whose names hold the frame number as\n"
          "                       %%d or %%04d (target guides; -o and the side outputs\n"
          "                       must);\n"
          "                       the exemplar and source guides are shared, sent to the\n"
          "                       workers once; frames run side by side on a coordinator\n",
          TS_STYLIT_MAX_GUIDES, TS_FRAME_LAST, TS_FRAMES_MAX);
  ts_paramopt_help(f, e);
  fprintf(f, "%s", ts_job_options_help);
}

enum { OPT_STYLE = TS_OPT_OWN, OPT_GUIDE, OPT_WEIGHT, OPT_FRAMES, OPT_IMAGE, OPT_JSON };

/* Its own options: the scene's images and weights, and the frames (the
 * parameters are the engine's). */
#define SCENE_LONGOPTS                                                                                 \
  {"style", required_argument, 0, OPT_STYLE}, {"guide", required_argument, 0, OPT_GUIDE},             \
      {"weight", required_argument, 0, OPT_WEIGHT}
static const struct option own_opts[] = {SCENE_LONGOPTS, {"frames", required_argument, 0, OPT_FRAMES},
                                         TS_JOB_LONGOPTS, {0, 0, 0, 0}};

typedef struct {
  ts_job_cmd job;
  int guides;
  int weighs; /* what --weight sets: -1 nothing yet, 0 the style, k + 1 guide k */
  int sequence; /* --frames given */
  ts_frames frames;
} stylize_opts;

/* --guide SRC TGT: getopt hands over SRC; TGT is the next word. */
static int guide_option(stylize_opts *o, int argc, char **argv, const char *src, char *err) {
  /* An option where TGT should be is a forgotten TGT, not a file name. */
  if (optind >= argc || (argv[optind][0] == '-' && argv[optind][1] != '\0'))
    return ts_error(err, TS_EINVAL, "--guide %s: needs a target guide after it (--guide SRC TGT)", src);
  if (o->guides == TS_STYLIT_MAX_GUIDES)
    return ts_error(err, TS_EINVAL, "--guide: at most %d guide pairs", TS_STYLIT_MAX_GUIDES);
  o->job.in[ts_stylit_in_src(o->guides)] = src;
  o->job.in[ts_stylit_in_tgt(o->guides)] = argv[optind++];
  o->weighs = ++o->guides;
  return 0;
}

static int weight_option(stylize_opts *o, const char *arg, char *err) {
  double w;
  if (o->weighs < 0)
    return ts_error(err, TS_EINVAL, "--weight %s: put it after the --style or --guide it weighs", arg);
  int rc = ts_arg_double("--weight", arg, &w, err);
  if (rc == 0 && w < 0) rc = ts_error(err, TS_EINVAL, "--weight %s: need 0 or 0.01..100", arg);
  char key[32];
  if (o->weighs == 0) snprintf(key, sizeof(key), "style_weight");
  else snprintf(key, sizeof(key), "weight_%d", o->weighs - 1);
  return rc != 0 ? rc : ts_job_set_key(&o->job, key, arg, "--weight", err);
}

/* The options that describe the scene, shared by stylize and energy:
 * TS_ENOENT when c is none of them. */
static int scene_option(stylize_opts *o, int c, int argc, char **argv, char *err) {
  switch (c) {
  case OPT_STYLE: o->job.in[TS_STYLIT_IN_STYLE] = optarg; o->weighs = 0; return 0;
  case OPT_GUIDE: return guide_option(o, argc, argv, optarg, err);
  case OPT_WEIGHT: return weight_option(o, optarg, err);
  default: return TS_ENOENT;
  }
}

static int stylize_option(void *ctx, int c, const char *arg, int argc, char **argv, char *err) {
  stylize_opts *o = ctx;
  if (c != OPT_FRAMES) return scene_option(o, c, argc, argv, err);
  o->sequence = 1;
  return ts_frames_parse(arg, &o->frames, err);
}

/* The scene's required parts, after the options. */
static int scene_complete(stylize_opts *o, const char *cmd, char *err) {
  if (o->job.in[TS_STYLIT_IN_STYLE] == NULL)
    return ts_error(err, TS_EINVAL, "--style EXEMPLAR is required (see texsyn %s --help)", cmd);
  if (o->guides == 0) return ts_error(err, TS_EINVAL, "at least one --guide SRC TGT is required");
  char n[16];
  snprintf(n, sizeof(n), "%d", o->guides);
  return ts_job_set_key(&o->job, "guides", n, "--guide", err);
}

/* '+': no reordering of argv, so the word after --guide SRC is its TGT. */
static int stylize_parse(int argc, char **argv, stylize_opts *o, char *err) {
  memset(o, 0, sizeof(*o));
  ts_job_cmd_init(&o->job, "stylize", ts_engine_find("stylize"));
  o->weighs = -1;
  static const ts_cmd_options cmd = {"+o:h", own_opts, stylize_option, usage};
  int rc = ts_paramopt_parse(&o->job, &cmd, o, argc, argv, err);
  if (rc != 0) return rc;
  rc = scene_complete(o, "stylize", err);
  return rc != 0 ? rc : ts_job_parse_end(&o->job, err);
}

int ts_cmd_stylize(int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  stylize_opts o;
  if (stylize_parse(argc, argv, &o, err) != 0) {
    fprintf(stderr, "texsyn stylize: %s\n", err);
    return 2;
  }
  if (!o.sequence) return ts_job_run(&o.job);
  const char *fixed[TS_ENGINE_MAX_INPUTS] = {"the style exemplar"};
  for (int k = 0; k < o.guides; k++) fixed[ts_stylit_in_src(k)] = "a source guide";
  return ts_job_run_frames(&o.job, &o.frames, fixed);
}

/* ---- texsyn energy ------------------------------------------------------ */

/* A job of the energy engine (energy_engine.c) like any other, run here or
 * on a coordinator by ts_job_run; its result, one JSON line, goes to a
 * temporary file and is printed from there, so the output is the same
 * bytes wherever the measure ran. */

static const char *const kEnergyUsage =
    "usage: texsyn energy --style EXEMPLAR --guide SRC TGT [--weight W] [--guide SRC TGT ...]\n"
    "                     --image OUT [--sample STEP] [--patch-size 5] [--json] [options]\n"
    "\n"
    "Scores any stylized image OUT of this scene, whatever made it: the mean, over the\n"
    "target patches at every STEP-th pixel in x and y (default 1: all), of the exact least\n"
    "guided distance to any exemplar patch - stylize's vectors (OUT in place of the style\n"
    "estimate, the target guides), weights and 8-bit conversions, no uniformity penalty -\n"
    "in grey levels per compared value. Coverage: the share of exemplar pixels covered\n"
    "by those best exemplar patches (each counts all its pixels). Lower energy is better.\n"
    "Prints one JSON object, as texsyn quality does: {\"energy\": E, \"coverage\": C, ...,\n"
    "\"samples\": N, \"step\": S, \"patch_size\": P}, the same bytes in-process and on a\n"
    "cluster (--server: the coordinator's workers run the search).\n"
    "\n"
    "  --style, --guide, --weight   the scene, as texsyn stylize takes it\n"
    "  --image OUT          the image to score: the target guides' size; 1 or 2\n"
    "                       channels for a grey style, 3 or 4 for a colour one\n"
    "  --json               the JSON object (the default; taken for older scripts)\n";

static const struct option energy_own[] = {SCENE_LONGOPTS, {"image", required_argument, 0, OPT_IMAGE},
                                           {"json", no_argument, 0, OPT_JSON}, TS_JOB_RUN_LONGOPTS,
                                           {0, 0, 0, 0}};

typedef struct {
  stylize_opts s;
  const char *image;
  char result[4096]; /* the temporary file the result goes to (mkstemp's template until made) */
} energy_opts;

static int energy_option(void *ctx, int c, const char *arg, int argc, char **argv, char *err) {
  energy_opts *o = ctx;
  if (c == OPT_IMAGE) o->image = arg;
  else if (c != OPT_JSON) return scene_option(&o->s, c, argc, argv, err); /* --json: JSON is what energy prints */
  return 0;
}

static void energy_usage(FILE *f, const ts_engine *e) {
  fprintf(f, "%s", kEnergyUsage);
  ts_paramopt_help(f, e);
  fprintf(f, "%s\nWith --detach, texsyn fetch ID -o F writes the JSON object to F.\n", TS_JOB_RUN_HELP);
}

/* The result's path is set here, made by energy_result_file. */
static int energy_parse(int argc, char **argv, energy_opts *o, char *err) {
  memset(o, 0, sizeof(*o));
  ts_job_cmd_init(&o->s.job, "energy", ts_engine_find("energy"));
  o->s.job.result_name = "energy";
  o->s.weighs = -1;
  static const ts_cmd_options cmd = {"+h", energy_own, energy_option, energy_usage};
  int rc = ts_paramopt_parse(&o->s.job, &cmd, o, argc, argv, err);
  if (rc != 0) return rc;
  if (o->image == NULL) return ts_error(err, TS_EINVAL, "--image OUT is required: the stylized image to score");
  rc = scene_complete(&o->s, "energy", err);
  if (rc != 0) return rc;
  o->s.job.in[1 + 2 * o->s.guides] = o->image;
  const char *dir = getenv("TMPDIR");
  snprintf(o->result, sizeof(o->result), "%s/texsyn-energy-XXXXXX", dir != NULL && dir[0] != '\0' ? dir : "/tmp");
  ts_output_set(&o->s.job.out, "output", o->result);
  return ts_job_parse_end(&o->s.job, err);
}

/* Makes the temporary result file, under the name the job was given. */
static int energy_result_file(energy_opts *o, char *err) {
  char tmpl[sizeof(o->result)];
  snprintf(tmpl, sizeof(tmpl), "%s", o->result);
  int fd = mkstemp(o->result);
  if (fd < 0)
    return ts_error(err, TS_EIO, "cannot make a temporary file %s for the result: %s (set TMPDIR to a writable "
                    "directory)", tmpl, strerror(errno));
  close(fd);
  return 0;
}

/* Prints the result the job wrote, one JSON object as texsyn quality's,
 * once it is checked to be the engine's. */
static int energy_print(const energy_opts *o, char *err) {
  uint8_t *buf = NULL;
  size_t len = 0;
  ts_stylit_energy en;
  char why[TS_ERR_LEN];
  int rc = ts_file_read(o->result, 4096, &buf, &len, err);
  if (rc == 0 && ts_stylit_energy_json_read((const char *)buf, len, &en, why) != 0)
    rc = ts_error(err, TS_EFORMAT, "the job's result (energy.json): %.400s", why);
  if (rc == 0) fwrite(buf, 1, len, stdout);
  free(buf);
  return rc;
}

int ts_cmd_energy(int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  energy_opts o;
  if (energy_parse(argc, argv, &o, err) != 0) {
    fprintf(stderr, "texsyn energy: %s\n", err);
    return 2;
  }
  if (energy_result_file(&o, err) != 0) {
    fprintf(stderr, "texsyn energy: %s\n", err);
    return 1;
  }
  int status = ts_job_run(&o.s.job);
  if (status == 0 && !o.s.job.detach && energy_print(&o, err) != 0) {
    fprintf(stderr, "texsyn energy: %s\n", err);
    status = 1;
  }
  unlink(o.result);
  return status;
}

/* ---- texsyn apply-nnf --------------------------------------------------- */

static const char *const kApplyUsage =
    "usage: texsyn apply-nnf --nnf F --source IMG -o OUT [--patch-size 5] [--size WxH]\n"
    "\n"
    "Re-applies a correspondence field saved by texsyn stylize --nnf to another layer\n"
    "IMG of the exemplar (same size), with stylize's vote: each OUT pixel is the rounded\n"
    "mean of what the patches covering it bring from IMG. Applied to the style exemplar\n"
    "itself, it gives the stylize output byte for byte. OUT is 8-bit with IMG's channels.\n"
    "  --patch-size P   the stylize job's patch size (default 5)\n"
    "  --size WxH       the output size, needed for a .raw NNF (it has no header)\n";

enum { OPT_NNF = OPT_JSON + 1, OPT_SOURCE, OPT_PATCH, OPT_SIZE };

static const struct option apply_longopts[] = {
    {"nnf", required_argument, 0, OPT_NNF},          {"source", required_argument, 0, OPT_SOURCE},
    {"output", required_argument, 0, 'o'},           {"patch-size", required_argument, 0, OPT_PATCH},
    {"size", required_argument, 0, OPT_SIZE},        {"help", no_argument, 0, TS_OPT_HELP},
    {0, 0, 0, 0}};

typedef struct {
  const char *nnf, *source, *out;
  int patch, w, h;
} apply_opts;

static int apply_option(apply_opts *o, int c, const char *arg, char *err) {
  long v;
  int rc = 0;
  switch (c) {
  case OPT_NNF: o->nnf = arg; break;
  case OPT_SOURCE: o->source = arg; break;
  case 'o': o->out = arg; break;
  case OPT_PATCH: rc = ts_arg_long("--patch-size", arg, -1000, 1000, &v, err); o->patch = (int)v; break;
  case OPT_SIZE:
    if (ts_parse_size(arg, 1 << 16, &o->w, &o->h) != 0)
      rc = ts_error(err, TS_EINVAL, "--size %s: expected WxH, e.g. 640x480", arg);
    break;
  default: rc = ts_arg_unknown("apply-nnf", arg, apply_longopts, err);
  }
  return rc;
}

static int apply_parse(int argc, char **argv, apply_opts *o, char *err) {
  *o = (apply_opts){NULL, NULL, NULL, 5, 0, 0};
  optind = 1;
  opterr = 0;
  int c;
  while ((c = getopt_long(argc, argv, "o:h", apply_longopts, NULL)) != -1) {
    if (c == TS_OPT_HELP || c == 'h') {
      printf("%s", kApplyUsage);
      exit(0);
    }
    int rc = apply_option(o, c, c == '?' || c == ':' ? argv[optind - 1] : optarg, err);
    if (rc != 0) return rc;
  }
  if (optind < argc) return ts_error(err, TS_EINVAL, "unexpected argument '%s'", argv[optind]);
  if (o->nnf == NULL || o->source == NULL || o->out == NULL)
    return ts_error(err, TS_EINVAL, "--nnf, --source and -o are required (see texsyn apply-nnf --help)");
  return 0;
}

static int is_raw(const char *path) {
  const char *dot = strrchr(path, '.');
  return dot != NULL && strcmp(dot, ".raw") == 0;
}

/* A .raw NNF: w x h little-endian uint32 (x, y) pairs, nothing else. */
static int read_nnf_raw(const char *path, int w, int h, uint32_t *nnf, char *err) {
  if (w == 0) return ts_error(err, TS_EINVAL, "%s: a .raw NNF has no header; give the output's --size WxH", path);
  FILE *f = fopen(path, "rb");
  if (f == NULL) return ts_error(err, TS_EIO, "cannot read %s: %m", path);
  size_t n = 2 * (size_t)w * (size_t)h;
  uint8_t b[4];
  size_t i = 0;
  for (; i < n && fread(b, 4, 1, f) == 1; i++)
    nnf[i] = (uint32_t)b[0] | (uint32_t)b[1] << 8 | (uint32_t)b[2] << 16 | (uint32_t)b[3] << 24;
  int extra = fread(b, 1, 1, f) == 1;
  fclose(f);
  if (i < n || extra)
    return ts_error(err, TS_EINVAL, "%s: %s than a %dx%d NNF (%zu bytes); is --size right?", path,
                    i < n ? "shorter" : "longer", w, h, 4 * n);
  return 0;
}

/* An image NNF: red = x / (sw - 1), green = y / (sh - 1), 16-bit, the
 * exemplar being sw x sh (exact back to the pixel while sw, sh <= 65536). */
static int read_nnf_image(const char *path, const ts_image *img, int sw, int sh, uint32_t *nnf, char *err) {
  if (img->type != TS_PIX_U16 || img->channels < 2)
    return ts_error(err, TS_EINVAL, "%s: not an NNF image (need 16-bit, red = x, green = y)", path);
  double kx = (sw - 1) / 65535.0, ky = (sh - 1) / 65535.0;
  const uint16_t *px = img->pixels;
  for (size_t i = 0; i < (size_t)img->width * (size_t)img->height; i++) {
    nnf[2 * i] = (uint32_t)(px[i * (size_t)img->channels] * kx + 0.5);
    nnf[2 * i + 1] = (uint32_t)(px[i * (size_t)img->channels + 1] * ky + 0.5);
  }
  return 0;
}

static int apply_nnf(const apply_opts *o, char *err) {
  ts_image src = {0}, map = {0}, out = {0};
  uint32_t *nnf = NULL;
  int rc = ts_image_read(o->source, &src, NULL, err), w = o->w, h = o->h;
  if (rc == 0 && !is_raw(o->nnf)) {
    rc = ts_image_read(o->nnf, &map, NULL, err);
    w = map.width;
    h = map.height;
  }
  if (rc == 0 && (nnf = malloc(2 * sizeof(*nnf) * ((size_t)w * (size_t)h + 1))) == NULL)
    rc = ts_error(err, TS_ENOMEM, "out of memory for a %dx%d NNF", w, h);
  if (rc == 0)
    rc = is_raw(o->nnf) ? read_nnf_raw(o->nnf, w, h, nnf, err)
                        : read_nnf_image(o->nnf, &map, src.width, src.height, nnf, err);
  if (rc == 0) rc = ts_stylit_apply_nnf(nnf, w, h, o->patch, &src, &out, err);
  if (rc == 0) rc = ts_image_write(o->out, &out, NULL, err);
  free(nnf);
  ts_image_free(&src);
  ts_image_free(&map);
  ts_image_free(&out);
  return rc;
}

int ts_cmd_apply_nnf(int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  apply_opts o;
  int rc = apply_parse(argc, argv, &o, err);
  if (rc == 0) rc = apply_nnf(&o, err);
  if (rc != 0) fprintf(stderr, "texsyn apply-nnf: %s\n", err);
  return rc == 0 ? 0 : rc == TS_EINVAL ? 2 : 1;
}
