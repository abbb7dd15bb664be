/* cli.c - the `texsyn` command line.
 *
 *   texsyn synth ...     synthesise a texture (embedded: in-process engine
 *                        and local scan threads; `run` is an alias)
 *   texsyn quality ...   neighbourhood error of an image against a reference
 *   texsyn shuffle ...   random block shuffle baseline
 *   texsyn simd          list the kernel variants this CPU supports
 */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "error.h"
#include "image.h"
#include "l1.h"
#include "mrf.h"
#include "outputs.h"
#include "quality.h"
#include "search.h"

#define DEFAULT_THREADS 2

static void usage_synth(FILE *f) {
  fprintf(f,
          "usage: texsyn synth --ref IMG -o OUT --size WxH [options]\n"
          "\n"
          "Synthesises a WxH texture that looks like IMG (multi-resolution MRF block\n"
          "synthesis after Stahlhut 2004). The output tiles seamlessly and has the\n"
          "reference's pixel type and channels; colour is gathered through the copy map.\n"
          "Exact: every block takes the globally best reference block (ties to the\n"
          "lowest index), so a job and seed give the same bytes on any machine.\n"
          "\n"
          "  --ref IMG            reference texture (PNG, JPEG, TIFF, OpenEXR, ...)\n"
          "  -o, --output OUT     output image; format from the extension\n"
          "  --size WxH           output size in pixels (any size, >= 1)\n"
          "  --levels L           pyramid levels, 1..%d (default 5)\n"
          "  --wn N               neighbourhood width, odd, > --wb, <= 41 (default 7)\n"
          "  --wb B               block width, odd, 1..15 (default 3)\n"
          "  --parity             parity control: compare only reference blocks of the\n"
          "                       same coordinate parity (4x fewer comparisons; removes\n"
          "                       oscillation, coarser transitions) (default off)\n"
          "  --usage-weight A     active usage-variance penalty, 0..100 (default 0 = off);\n"
          "                       A = 1 charges a block used at the average rate one grey\n"
          "                       level per neighbourhood pixel\n"
          "  --coarse-weight W    weight of the coarse-level part relative to equal\n"
          "                       weighting by area, (0, 100] (default 1)\n"
          "  --refine N           refinement sweeps, 0..20 (default 2): each block searched\n"
          "                       again with its full window - all blocks of the coarser\n"
          "                       levels, the band along the torus seam on the finest;\n"
          "                       better joins and seam, ~1/10 of level 0's time per sweep\n"
          "  --seed S             noise initialisation seed, 0..2^64-1 (default 1)\n"
          "  --rgb-search         search on the colour channels instead of luminance\n"
          "  --threads T          scan threads, 1..1024 (default %d)\n"
          "  --copy-map F         copy map as an image (red = source x, green = source y)\n"
          "  --copy-map-raw F     copy map as raw little-endian uint32 (x, y) per pixel\n"
          "  --usage-map F        usage map: counts per reference pixel (.tif/.exr as\n"
          "                       float counts; other formats normalised to the maximum)\n"
          "  --report F           JSON report: parameters, timings, statistics\n"
          "  --max-pixels N       refuse inputs and outputs above N pixels (default %llu)\n"
          "  --stop-level N       stop after pyramid level N and write its luminance at\n"
          "                       that level's size: a quick preview (default 0 = full)\n"
          "  --quiet              no progress bar\n"
          "\n"
          "TEXSYN_SIMD=scalar|mmx|sse2|avx2|avx512 forces a kernel variant.\n",
          TS_MRF_MAX_LEVELS, DEFAULT_THREADS, (unsigned long long)TS_IMAGE_DEFAULT_MAX_PIXELS);
}

/* ---- argument parsing helpers ----------------------------------------- */

static int parse_long(const char *opt, const char *s, long lo, long hi, long *out, char *err) {
  char *end;
  errno = 0;
  long v = strtol(s, &end, 10);
  if (errno != 0 || end == s || *end != '\0' || v < lo || v > hi)
    return ts_error(err, TS_EINVAL, "%s %s: need a whole number in %ld..%ld", opt, s, lo, hi);
  *out = v;
  return 0;
}

static int parse_u64(const char *opt, const char *s, uint64_t *out, char *err) {
  char *end;
  errno = 0;
  unsigned long long v = strtoull(s, &end, 10);
  if (errno != 0 || end == s || *end != '\0' || s[0] == '-')
    return ts_error(err, TS_EINVAL, "%s %s: need a whole number >= 0", opt, s);
  *out = v;
  return 0;
}

static int parse_double(const char *opt, const char *s, double *out, char *err) {
  char *end;
  errno = 0;
  double v = strtod(s, &end);
  if (errno != 0 || end == s || *end != '\0' || !isfinite(v))
    return ts_error(err, TS_EINVAL, "%s %s: need a number", opt, s);
  *out = v;
  return 0;
}

static int parse_size(const char *s, int *w, int *h, char *err) {
  char *end;
  long a = strtol(s, &end, 10);
  if (end == s || (*end != 'x' && *end != 'X'))
    return ts_error(err, TS_EINVAL, "--size %s: expected WxH, e.g. 1024x1024", s);
  const char *rest = end + 1;
  long b = strtol(rest, &end, 10);
  if (end == rest || *end != '\0' || a < 1 || b < 1 || a > 1000000 || b > 1000000)
    return ts_error(err, TS_EINVAL, "--size %s: expected WxH with 1..1000000 each", s);
  *w = (int)a;
  *h = (int)b;
  return 0;
}

/* ---- progress bar ------------------------------------------------------ */

typedef struct {
  int enabled;
  double start, last;
} progress_bar;

static double now_seconds(void) {
  struct timespec ts;
  clock_gettime(CLOCK_MONOTONIC, &ts);
  return ts.tv_sec + ts.tv_nsec * 1e-9;
}

static void progress_draw(void *ctx, const ts_mrf_progress *p) {
  progress_bar *pb = ctx;
  double t = now_seconds();
  int level_done = p->done == p->total;
  if (!pb->enabled || (t - pb->last < 0.1 && !level_done)) return;
  pb->last = t;
  double frac = p->work_total > 0 ? p->work_done / p->work_total : 1.0;
  double eta = frac > 0.001 ? (t - pb->start) * (1.0 - frac) / frac : 0.0;
  int pct = p->total ? (int)(100 * p->done / p->total) : 100;
  char bar[31];
  int fill = (int)(frac * 30);
  for (int i = 0; i < 30; i++) bar[i] = i < fill ? '#' : '.';
  bar[30] = '\0';
  fprintf(stderr, "\rlevel %d (%d of %d) %3d%% of blocks [%s] ETA %5.1fs ", p->level,
          p->levels - p->level, p->levels, pct, bar, eta);
  fflush(stderr);
}

/* ---- synth ------------------------------------------------------------- */

typedef struct {
  ts_mrf_params p;
  const char *ref, *out, *copy_map, *copy_map_raw, *usage_map, *report;
  int threads, quiet, have_size;
} synth_opts;

enum {
  OPT_REF = 256, OPT_SIZE, OPT_LEVELS, OPT_WN, OPT_WB, OPT_PARITY, OPT_USAGE, OPT_COARSE,
  OPT_SEED, OPT_RGB, OPT_THREADS, OPT_COPY, OPT_COPY_RAW, OPT_USAGE_MAP, OPT_REPORT,
  OPT_MAXPIX, OPT_STOP, OPT_REFINE, OPT_QUIET, OPT_HELP, OPT_IMAGE, OPT_SAMPLES, OPT_BLOCK
};

static const struct option synth_longopts[] = {
    {"ref", required_argument, 0, OPT_REF},
    {"output", required_argument, 0, 'o'},
    {"size", required_argument, 0, OPT_SIZE},
    {"levels", required_argument, 0, OPT_LEVELS},
    {"wn", required_argument, 0, OPT_WN},
    {"wb", required_argument, 0, OPT_WB},
    {"parity", no_argument, 0, OPT_PARITY},
    {"usage-weight", required_argument, 0, OPT_USAGE},
    {"coarse-weight", required_argument, 0, OPT_COARSE},
    {"seed", required_argument, 0, OPT_SEED},
    {"rgb-search", no_argument, 0, OPT_RGB},
    {"threads", required_argument, 0, OPT_THREADS},
    {"copy-map", required_argument, 0, OPT_COPY},
    {"copy-map-raw", required_argument, 0, OPT_COPY_RAW},
    {"usage-map", required_argument, 0, OPT_USAGE_MAP},
    {"report", required_argument, 0, OPT_REPORT},
    {"max-pixels", required_argument, 0, OPT_MAXPIX},
    {"stop-level", required_argument, 0, OPT_STOP},
    {"refine", required_argument, 0, OPT_REFINE},
    {"quiet", no_argument, 0, OPT_QUIET},
    {"help", no_argument, 0, OPT_HELP},
    {0, 0, 0, 0}};

static int synth_option(synth_opts *o, int c, const char *arg, char *err) {
  long v;
  int rc = 0;
  switch (c) {
  case OPT_REF: o->ref = arg; break;
  case 'o': o->out = arg; break;
  case OPT_SIZE: rc = parse_size(arg, &o->p.width, &o->p.height, err); o->have_size = 1; break;
  case OPT_LEVELS: rc = parse_long("--levels", arg, -1000, 1000, &v, err); o->p.levels = (int)v; break;
  case OPT_WN: rc = parse_long("--wn", arg, -1000, 1000, &v, err); o->p.wn = (int)v; break;
  case OPT_WB: rc = parse_long("--wb", arg, -1000, 1000, &v, err); o->p.wb = (int)v; break;
  case OPT_PARITY: o->p.parity = 1; break;
  case OPT_USAGE: rc = parse_double("--usage-weight", arg, &o->p.usage_weight, err); break;
  case OPT_COARSE: rc = parse_double("--coarse-weight", arg, &o->p.coarse_weight, err); break;
  case OPT_SEED: rc = parse_u64("--seed", arg, &o->p.seed, err); break;
  case OPT_RGB: o->p.rgb_search = 1; break;
  case OPT_THREADS: rc = parse_long("--threads", arg, 1, 1024, &v, err); o->threads = (int)v; break;
  case OPT_COPY: o->copy_map = arg; break;
  case OPT_COPY_RAW: o->copy_map_raw = arg; break;
  case OPT_USAGE_MAP: o->usage_map = arg; break;
  case OPT_REPORT: o->report = arg; break;
  case OPT_MAXPIX: rc = parse_u64("--max-pixels", arg, &o->p.max_pixels, err); break;
  case OPT_STOP: rc = parse_long("--stop-level", arg, -1000, 1000, &v, err); o->p.stop_level = (int)v; break;
  case OPT_REFINE: rc = parse_long("--refine", arg, -1000, 1000, &v, err); o->p.refine = (int)v; break;
  case OPT_QUIET: o->quiet = 1; break;
  default: rc = ts_error(err, TS_EINVAL, "unknown option (see texsyn synth --help)");
  }
  return rc;
}

static int synth_parse(int argc, char **argv, synth_opts *o, char *err) {
  memset(o, 0, sizeof(*o));
  ts_mrf_params_default(&o->p);
  o->threads = DEFAULT_THREADS;
  optind = 1;
  opterr = 0;
  int c;
  while ((c = getopt_long(argc, argv, "o:h", synth_longopts, NULL)) != -1) {
    if (c == OPT_HELP || c == 'h') {
      usage_synth(stdout);
      exit(0);
    }
    if (c == '?' || c == ':')
      return ts_error(err, TS_EINVAL, "%s: unknown option or missing value (see texsyn synth --help)",
                      argv[optind - 1]);
    int rc = synth_option(o, c, optarg, err);
    if (rc != 0) return rc;
  }
  if (optind < argc) return ts_error(err, TS_EINVAL, "unexpected argument '%s'", argv[optind]);
  if (o->ref == NULL) return ts_error(err, TS_EINVAL, "--ref IMG is required (see texsyn synth --help)");
  if (o->out == NULL) return ts_error(err, TS_EINVAL, "-o OUT is required (see texsyn synth --help)");
  if (!o->have_size) return ts_error(err, TS_EINVAL, "--size WxH is required (see texsyn synth --help)");
  return 0;
}

static int write_outputs(const synth_opts *o, const ts_image *ref, const ts_mrf_result *res,
                         const ts_search *search, char *err) {
  int rc = ts_image_write(o->out, &res->image, ref->meta, err);
  if (rc == 0 && o->copy_map)
    rc = ts_write_copy_map_image(o->copy_map, res->copy_map, res->image.width, res->image.height,
                                 res->ref_w, res->ref_h, err);
  if (rc == 0 && o->copy_map_raw)
    rc = ts_write_copy_map_raw(o->copy_map_raw, res->copy_map, res->image.width, res->image.height, err);
  if (rc == 0 && o->usage_map)
    rc = ts_write_usage_map(o->usage_map, res->usage, res->ref_w, res->ref_h, err);
  if (rc == 0 && o->report) rc = ts_write_report(o->report, &o->p, o->threads, search, res, err);
  return rc;
}

static int cmd_synth(int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  synth_opts o;
  int rc = synth_parse(argc, argv, &o, err);
  if (rc != 0) {
    fprintf(stderr, "texsyn synth: %s\n", err);
    return 2;
  }
  ts_image_limits limits = {o.p.max_pixels};
  ts_image ref = {0};
  rc = ts_image_read(o.ref, &ref, &limits, err);
  if (rc != 0) {
    fprintf(stderr, "texsyn synth: %s\n", err);
    return 1;
  }
  char msg[2048];
  if (ts_mrf_check(&o.p, ref.width, ref.height, ref.channels, msg, sizeof(msg)) != 0) {
    fprintf(stderr, "texsyn synth: invalid parameters for reference %s (%dx%d):\n%s\n", o.ref,
            ref.width, ref.height, msg);
    ts_image_free(&ref);
    return 2;
  }
  ts_search *search = NULL;
  rc = ts_search_local_create(&search, o.threads, NULL, err);
  ts_mrf_result res;
  progress_bar pb = {!o.quiet && isatty(STDERR_FILENO), now_seconds(), 0};
  if (rc == 0) rc = ts_mrf_synthesize(&o.p, &ref, search, progress_draw, &pb, &res, err);
  if (pb.enabled) fputc('\n', stderr);
  if (rc == 0) {
    rc = write_outputs(&o, &ref, &res, search, err);
    if (rc == 0 && !o.quiet)
      fprintf(stderr, "texsyn: %s %dx%d in %.2fs (%s, %d threads, %.3g comparisons)\n", o.out,
              o.p.width, o.p.height, res.seconds, search->simd->name, o.threads,
              (double)search->stats.pairs);
    ts_mrf_result_free(&res);
  }
  if (rc != 0) fprintf(stderr, "texsyn synth: %s\n", err);
  ts_search_destroy(search);
  ts_image_free(&ref);
  return rc == 0 ? 0 : 1;
}

/* ---- quality and shuffle ---------------------------------------------- */

static int read_luma(const char *path, ts_plane *pl, char *err) {
  ts_image img = {0};
  int rc = ts_image_read(path, &img, NULL, err);
  if (rc != 0) return rc;
  rc = ts_plane_alloc(pl, img.width, img.height);
  if (rc == 0) ts_image_luma8(&img, pl->px);
  else ts_error(err, rc, "out of memory");
  ts_image_free(&img);
  return rc;
}

static const struct option eval_longopts[] = {
    {"ref", required_argument, 0, OPT_REF},       {"image", required_argument, 0, OPT_IMAGE},
    {"output", required_argument, 0, 'o'},        {"size", required_argument, 0, OPT_SIZE},
    {"wn", required_argument, 0, OPT_WN},         {"block", required_argument, 0, OPT_BLOCK},
    {"samples", required_argument, 0, OPT_SAMPLES}, {"seed", required_argument, 0, OPT_SEED},
    {"threads", required_argument, 0, OPT_THREADS}, {"help", no_argument, 0, OPT_HELP},
    {0, 0, 0, 0}};

typedef struct {
  const char *ref, *image, *out;
  int w, h, wn, block, threads;
  long samples;
  uint64_t seed;
} eval_opts;

static int eval_parse(int argc, char **argv, eval_opts *o, const char *usage, char *err) {
  *o = (eval_opts){NULL, NULL, NULL, 0, 0, 7, 16, DEFAULT_THREADS, 2000, 1};
  optind = 1;
  opterr = 0;
  int c, rc = 0;
  long v;
  while (rc == 0 && (c = getopt_long(argc, argv, "o:h", eval_longopts, NULL)) != -1) {
    switch (c) {
    case OPT_REF: o->ref = optarg; break;
    case OPT_IMAGE: o->image = optarg; break;
    case 'o': o->out = optarg; break;
    case OPT_SIZE: rc = parse_size(optarg, &o->w, &o->h, err); break;
    case OPT_WN: rc = parse_long("--wn", optarg, 3, TS_MAX_WN, &v, err); o->wn = (int)(v | 1); break;
    case OPT_BLOCK: rc = parse_long("--block", optarg, 1, 4096, &v, err); o->block = (int)v; break;
    case OPT_SAMPLES: rc = parse_long("--samples", optarg, 1, 10000000, &o->samples, err); break;
    case OPT_SEED: rc = parse_u64("--seed", optarg, &o->seed, err); break;
    case OPT_THREADS: rc = parse_long("--threads", optarg, 1, 1024, &v, err); o->threads = (int)v; break;
    case OPT_HELP: case 'h': printf("%s", usage); exit(0);
    default: rc = ts_error(err, TS_EINVAL, "unknown option or missing value\n%s", usage);
    }
  }
  return rc;
}

static const char *kQualityUsage =
    "usage: texsyn quality --ref REF --image IMG [--wn 7] [--samples 2000] [--seed 1] [--threads T]\n"
    "Prints the mean exact best-match error (grey levels per pixel) of WNxWN windows of IMG\n"
    "(read on the torus) against REF, for inner windows and for windows across the tiling seam.\n";

static int cmd_quality(int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  eval_opts o;
  int rc = eval_parse(argc, argv, &o, kQualityUsage, err);
  if (rc == 0 && (o.ref == NULL || o.image == NULL))
    rc = ts_error(err, TS_EINVAL, "--ref and --image are required\n%s", kQualityUsage);
  ts_plane ref = {0}, img = {0};
  ts_search *search = NULL;
  ts_quality q;
  if (rc == 0) rc = read_luma(o.ref, &ref, err);
  if (rc == 0) rc = read_luma(o.image, &img, err);
  if (rc == 0) rc = ts_search_local_create(&search, o.threads, NULL, err);
  if (rc == 0) rc = ts_quality_measure(search, &ref, &img, o.wn, (uint32_t)o.samples, o.seed, &q, err);
  if (rc == 0)
    printf("{\"wn\": %d, \"inner_mean\": %.4f, \"inner_n\": %u, \"seam_mean\": %.4f, \"seam_n\": %u}\n",
           o.wn, q.mean_inner, q.n_inner, q.mean_seam, q.n_seam);
  else
    fprintf(stderr, "texsyn quality: %s\n", err);
  ts_search_destroy(search);
  ts_plane_free(&ref);
  ts_plane_free(&img);
  return rc == 0 ? 0 : 1;
}

static const char *kShuffleUsage =
    "usage: texsyn shuffle --ref REF -o OUT --size WxH [--block 16] [--seed 1]\n"
    "Tiles OUT with BLOCKxBLOCK blocks of REF taken at random positions (a baseline).\n";

static int cmd_shuffle(int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  eval_opts o;
  int rc = eval_parse(argc, argv, &o, kShuffleUsage, err);
  if (rc == 0 && (o.ref == NULL || o.out == NULL || o.w == 0))
    rc = ts_error(err, TS_EINVAL, "--ref, -o and --size are required\n%s", kShuffleUsage);
  ts_image ref = {0}, out = {0};
  uint32_t *map = NULL;
  if (rc == 0) rc = ts_image_read(o.ref, &ref, NULL, err);
  if (rc == 0 && (map = malloc(sizeof(uint32_t) * 2 * (size_t)o.w * o.h)) == NULL)
    rc = ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) {
    ts_plane shape = {ref.width, ref.height, NULL};
    rc = ts_shuffle_blocks(&shape, o.w, o.h, o.block, o.seed, map);
    if (rc != 0) ts_error(err, rc, "--block %d does not fit the %dx%d reference", o.block, ref.width, ref.height);
  }
  if (rc == 0) rc = ts_image_alloc(&out, o.w, o.h, ref.channels, ref.type, err);
  if (rc == 0) {
    for (long i = 0; i < (long)o.w * o.h; i++)
      ts_image_copy_pixel(&out, (int)(i % o.w), (int)(i / o.w), &ref, (int)map[2 * i], (int)map[2 * i + 1]);
    rc = ts_image_write(o.out, &out, ref.meta, err);
  }
  if (rc != 0) fprintf(stderr, "texsyn shuffle: %s\n", err);
  free(map);
  ts_image_free(&out);
  ts_image_free(&ref);
  return rc == 0 ? 0 : 1;
}

static int cmd_simd(void) {
  const ts_l1_impl *sel = NULL;
  char err[TS_ERR_LEN];
  int rc = ts_l1_select(&sel, err);
  for (int i = 0; i < TS_SIMD_COUNT; i++) {
    const ts_l1_impl *impl = ts_l1_impl_get((ts_simd)i);
    if (impl) printf("%s%s\n", impl->name, impl == sel ? " (selected)" : "");
  }
  if (rc != 0) fprintf(stderr, "texsyn simd: %s\n", err);
  return rc == 0 ? 0 : 1;
}

static void usage_main(FILE *f) {
  fprintf(f,
          "usage: texsyn COMMAND [options]   (texsyn COMMAND --help for details)\n"
          "  synth    synthesise a texture from a reference (alias: run)\n"
          "  quality  neighbourhood error of an image against a reference\n"
          "  shuffle  random block shuffle of a reference (a baseline)\n"
          "  simd     list the L1 kernel variants this CPU supports\n");
}

int main(int argc, char **argv) {
  if (argc < 2) {
    usage_main(stderr);
    return 2;
  }
  const char *cmd = argv[1];
  if (strcmp(cmd, "synth") == 0 || strcmp(cmd, "run") == 0) return cmd_synth(argc - 1, argv + 1);
  if (strcmp(cmd, "quality") == 0) return cmd_quality(argc - 1, argv + 1);
  if (strcmp(cmd, "shuffle") == 0) return cmd_shuffle(argc - 1, argv + 1);
  if (strcmp(cmd, "simd") == 0) return cmd_simd();
  if (strcmp(cmd, "--help") == 0 || strcmp(cmd, "-h") == 0 || strcmp(cmd, "help") == 0) {
    usage_main(stdout);
    return 0;
  }
  fprintf(stderr, "texsyn: unknown command '%s'\n", cmd);
  usage_main(stderr);
  return 2;
}
