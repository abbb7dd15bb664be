/* mrf_params.c - the parameters of MRF block synthesis (mrf.h), declared
 * once (param.h): the spec, the defaults, the ranges, `texsyn synth`'s
 * options and their --help all come from this table. */
#include <stddef.h>
#include <stdio.h>
#include <string.h>

#include "error.h"
#include "image.h"
#include "lbg.h"
#include "mrf.h"
#include "neigh.h"
#include "param.h"

int ts_mrf_lbg_levels_parse(const char *spec, uint32_t *mask) {
  if (strcmp(spec, "all") == 0) {
    *mask = TS_MRF_LBG_ALL;
    return 0;
  }
  uint32_t m = 0;
  for (const char *s = spec;; s++) {
    int level = 0, digits = 0;
    for (; *s >= '0' && *s <= '9' && digits < 3; s++, digits++) level = 10 * level + (*s - '0');
    if (digits == 0 || level >= TS_MRF_MAX_LEVELS) return TS_EINVAL;
    m |= 1u << level;
    if (*s == '\0') break;
    if (*s != ',') return TS_EINVAL;
  }
  *mask = m;
  return 0;
}

void ts_mrf_lbg_levels_format(uint32_t mask, char *buf, size_t cap) {
  size_t at = 0;
  buf[0] = '\0';
  if (mask == TS_MRF_LBG_ALL) {
    snprintf(buf, cap, "all");
    return;
  }
  for (int l = 0; l < 32 && at < cap; l++)
    if (mask >> l & 1) {
      int n = snprintf(buf + at, cap - at, "%s%d", at ? "," : "", l);
      if (n < 0) break;
      at += (size_t)n;
    }
}

static int levels_parse(const char *text, void *field) { return ts_mrf_lbg_levels_parse(text, field); }
static void levels_format(const void *field, char *buf, size_t cap) {
  ts_mrf_lbg_levels_format(*(const uint32_t *)field, buf, cap);
}
static const ts_param_codec lbg_levels_codec = {levels_parse, levels_format,
                                                "\"all\" or level numbers 0..11 separated by commas, e.g. 0,1"};
_Static_assert(TS_MRF_MAX_LEVELS == 12, "the lbg_levels codec's message names the levels");

#define F(field) offsetof(ts_mrf_params, field)
enum { G_BEST_OF = 1, G_MIX, G_ACCEL, G_LBG };

/* In the spec's order: a spec written by an earlier texsyn reads back to
 * the same text. */
const ts_param ts_mrf_param_table[] = {
    {"size", "size", "WxH", TS_PARAM_SIZE, F(width), 0, 0, NULL, "output size in pixels (any size, >= 1)"},
    {"levels", "levels", "L", TS_PARAM_INT, F(levels), 1, TS_MRF_MAX_LEVELS, "5", "pyramid levels",
     "5, or as many as a smaller --size holds"},
    {"wn", "wn", "N", TS_PARAM_INT, F(wn), 3, TS_MAX_WN, "7", "neighbourhood width, wider than --wb",
     .flags = TS_PARAM_ODD},
    {"wb", "wb", "B", TS_PARAM_INT, F(wb), 1, 15, "3", "block width", .flags = TS_PARAM_ODD},
    {"parity", "parity", NULL, TS_PARAM_FLAG, F(parity), 0, 1, "0",
     "parity control: compare only reference blocks of the same coordinate parity (4x fewer comparisons; "
     "removes oscillation, coarser transitions)"},
    {"usage_weight", "usage-weight", "A", TS_PARAM_DOUBLE, F(usage_weight), 0, 100, "0",
     "active usage-variance penalty (0 = off); A = 1 charges a block used at the average rate one grey level "
     "per neighbourhood pixel"},
    {"coarse_weight", "coarse-weight", "W", TS_PARAM_DOUBLE, F(coarse_weight), 0, 100, "1",
     "weight of the coarse-level part relative to equal weighting by area", .flags = TS_PARAM_MIN_OPEN},
    {"refine", "refine", "N", TS_PARAM_INT, F(refine), 0, 20, "2",
     "refinement sweeps: each block searched again with its full window - all blocks of the coarser levels, "
     "the band along the torus seam on the finest; better joins and seam, ~1/10 of level 0's time per sweep"},
    {"seed", "seed", "S", TS_PARAM_U64, F(seed), 0, 0, "1", "noise initialisation seed",
     .flags = TS_PARAM_UNBOUNDED},
    {"rgb_search", "rgb-search", NULL, TS_PARAM_FLAG, F(rgb_search), 0, 1, "0",
     "search on the colour channels instead of luminance"},
    {"max_pixels", NULL, NULL, TS_PARAM_U64, F(max_pixels), 0, 0, "268435456", "output size limit",
     .flags = TS_PARAM_UNBOUNDED},
    {"stop_level", "stop-level", "N", TS_PARAM_INT, F(stop_level), 0, TS_MRF_MAX_LEVELS - 1, "0",
     "stop after pyramid level N and write its luminance at that level's size: a quick preview, embedded only "
     "(0 = full)", .flags = TS_PARAM_EMBEDDED},
    {"best_of", "best-of", "K", TS_PARAM_INT, F(best_of), 1, TS_MRF_MAX_BEST_OF, "1",
     "passive usage-variance optimisation: K seeds (the first --seed) through the coarse levels, the one whose "
     "usage map has the least variance goes on (1 = off)", .group = G_BEST_OF},
    {"best_of_levels", "best-of-levels", "N", TS_PARAM_INT, F(best_of_levels), 0, TS_MRF_MAX_LEVELS, "0",
     "how many of the coarsest levels the --best-of candidates run", "all but the finest two", .group = G_BEST_OF},
    {"mix_level", "mix-level", "M", TS_PARAM_INT, F(mix_level), 0, TS_MRF_MAX_LEVELS - 1, "0",
     "texture mixing with --ref-fine: the first level made from --ref, below --levels (0 = no mixing)",
     .group = G_MIX},
    {"copy_accel", "copy-accel", NULL, TS_PARAM_FLAG, F(copy_accel), 0, 1, "0",
     "copy-map shortcut (LOSSY): at levels 1 and 0, blocks inside coherent regions of the level above's copy "
     "map are copied without a search, once the levels above kept their regions (the report and the image's "
     "metadata say so; the job takes no checkpoints)", .group = G_ACCEL},
    {"copy_accel_kernel", "copy-accel-kernel", "N", TS_PARAM_INT, F(accel_kernel), 0, 15, "0",
     "coherence kernel width: the buffer kept to transitions", "the coarse window width W_C", .group = G_ACCEL,
     .flags = TS_PARAM_ODD},
    {"copy_accel_min", "copy-accel-min", "R", TS_PARAM_DOUBLE, F(accel_min), 0, 1, "0.95",
     "constancy the levels above must show", .group = G_ACCEL},
    {"lbg", "lbg", "P", TS_PARAM_INT, F(lbg), 0, TS_LBG_MAX_PARTITIONS, "0",
     "LOSSY: search in P LBG partitions per class (seed 002 §3.6.5): each block only in its nearest "
     "partition(s); 0 = off (exact search); a set queried too seldom for its codebook to pay stays exact",
     .group = G_LBG},
    {"lbg_levels", "lbg-levels", "SPEC", TS_PARAM_CUSTOM, F(lbg_levels), 0, 0, "0",
     "levels searched so: \"all\" or a list like 0,1", .group = G_LBG, .codec = &lbg_levels_codec},
    {"lbg_probe", "lbg-probe", "N", TS_PARAM_INT, F(lbg_probe), 1, TS_LBG_MAX_PARTITIONS, "1",
     "partitions scanned per block, at most --lbg", .group = G_LBG},
    {"lbg_exact", "lbg-exact", NULL, TS_PARAM_FLAG, F(lbg_exact), 0, 1, "0",
     "exact pruning instead: skip only partitions that cannot hold a better block (the exact search's bytes)",
     .group = G_LBG},
    {NULL}};

void ts_mrf_params_default(ts_mrf_params *p) {
  memset(p, 0, sizeof(*p));
  ts_params_default(ts_mrf_param_table, p);
}
