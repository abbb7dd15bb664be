/* stylit.h - guided stylization after StyLit (Fišer et al. 2016) with
 * Kaspar's occurrence-map uniformity term (seed 001, digest 001-004):
 * paint a target in the style of a painted exemplar, guided by pairs of
 * images (render passes, segmentations) that say which source region
 * should go where.
 *
 * Inputs: the style exemplar A', and per guide K a source guide A_K (the
 * exemplar's size) and a target guide B_K (the output's size). Output: B',
 * the target painted with the exemplar's patches.
 *
 * Method, coarse to fine over a pyramid of all inputs:
 *
 *   level start   NNF: seeded random source patches (coarsest level), or
 *                 the level above's, doubled (NNF_up(x, y) =
 *                 2 NNF(x/2, y/2) + (x & 1, y & 1), clamped to the source
 *                 patches); the occurrence map Ω rebuilt from it.
 *   K times       vote: every target pixel becomes the mean of the style
 *                 pixels the patches covering it bring (below);
 *                 search: every target patch takes the source patch with
 *                 the least  sum_parts w_part * L1(part) + λ-penalty(Ω),
 *                 exactly (ties to the lowest source index), through the
 *                 search service; Ω rebuilt from the new NNF.
 *   end           a last vote of the finest NNF gives the output.
 *
 * Patches: p x p squares (p odd, r = p / 2) centred on a pixel. Source
 * patches lie wholly inside the exemplar (centres r .. size - r - 1); the
 * target has a patch at every pixel, reading past its edges as the edge
 * pixel repeated, so every target pixel has an NNF entry.
 *
 * Vectors: the style's colour channels and every guide's, each a part of
 * its own (window.h), weighted by w / channels of the part (so a weight is
 * what the whole image counts, whatever its channels: the style 1 by
 * default, each of N guides 1/N), in 1/840 steps.
 *
 * Uniformity: Ω counts, per source pixel, the target patches whose source
 * patch covers it; the penalty of a source patch is
 * λ * D1 * (sum of Ω over its p x p pixels) / E, with E that sum under
 * perfectly even use and D1 the distance of a one-grey-level error in
 * every component (usage.h): λ = 1 charges a patch used at the average
 * rate as much as one grey level of error everywhere. Ω is frozen for
 * each search step (all its batches see the Ω of the NNF it starts from)
 * and rebuilt after it: the result is a function of the inputs and the
 * seed, never of the batching, the threads or the workers.
 *
 * Vote: the mean, rounded to nearest, of the up to p^2 votes a pixel gets.
 * The median would minimise the L1 energy per pixel, but it picks one
 * patch's value and keeps the joins between patches visible; the mean
 * (the L2 optimum, as in StyLit and Kwatra's texture optimisation) blends
 * them, at the price of slight blur where the votes disagree.
 *
 * Types: every input is turned into 8-bit planes. 8- and 16-bit channels
 * keep their full range (16-bit to 8-bit rounds); float and half guide
 * channels, which have no fixed range (render passes), are stretched per
 * channel from the least to the greatest value of that channel over both
 * images of the pair, so the source and target guide stay comparable
 * (NaN reads as the least). A float style is read in [0, 1]. Colour
 * channels are the first three (the first of a grey image); an alpha
 * channel is not compared but is voted into the output, which is 8-bit
 * with the style's channels. */
#ifndef TS_STYLIT_H
#define TS_STYLIT_H

#include <stddef.h>
#include <stdint.h>

#include "image.h"
#include "progress.h"
#include "search.h"

#include "stylit_input.h"
#include "stylit_params.h"

typedef struct {
  double seconds;
  uint64_t pairs, queries;
  int w, h;  /* target size at the level */
  int mode;  /* TS_STYLIT_EXACT or TS_STYLIT_PATCHMATCH: what ran */
  double estimate; /* auto: the exact level's estimated seconds (0: not estimated) */
} ts_stylit_level_stats;

typedef struct {
  ts_image image;  /* 8-bit, the style's channels, the target's size */
  uint32_t *nnf;   /* x, y of the source pixel of each target pixel */
  int src_w, src_h;
  int levels;
  double coverage; /* share of source pixels some output patch covers */
  double seconds;
  double rate;     /* auto: the comparisons a second its estimates assumed */
  ts_stylit_level_stats level[TS_STYLIT_MAX_LEVELS];
} ts_stylit_result;

/* The p x p window over pl's planes, anchored at a patch's top-left corner
 * (so the usage block of an anchor is its patch): one part for the style,
 * one per guide, each weighted by its weight per channel. */
int ts_stylit_window(ts_window *win, const ts_stylit_params *p, const ts_stylit_planes *pl, char *err);
/* The query image: n planes of one size with r pixels of border, each the
 * nearest edge pixel, so the patch of every pixel lies inside it; the
 * patch of pixel (x, y) is the window at (x, y). 0 or TS_ENOMEM (the
 * caller frees pad[0..n-1] either way). */
int ts_stylit_pad(const ts_plane *const *t, int n, int r, ts_plane *pad);
/* counts (ncounts, sw wide) = per source pixel, the patches of radius r
 * centred on the n NNF entries (x, y pairs) that cover it. */
void ts_stylit_occurrences(const uint32_t *nnf, size_t n, int r, int sw, uint32_t *counts, size_t ncounts);
/* out[c] (tw x th) = the rounded mean of what the patches covering each
 * pixel bring from src[c] (whose centres the NNF gives), for n planes. */
void ts_stylit_vote(const uint32_t *nnf, int tw, int th, int r, const ts_plane *src, int n, uint8_t *const *out);

/* Runs a checked job. 0, or a TS_E* code with a message. */
int ts_stylit_run(const ts_stylit_params *p, const ts_image *const *in, ts_search *search, const ts_progress_hooks *h,
                  ts_stylit_result *res, char *err);
void ts_stylit_result_free(ts_stylit_result *res);

/* ---- quality tools (stylit_energy.c) ------------------------------------
 *
 * Energy: a score of any stylized image B' of the job's target, whatever
 * made it. Target patches are sampled at every step-th pixel in x and y
 * (from (0, 0); patches past the edges read the edge pixel, as in the
 * engine); each gets its exact least guided distance to any source patch:
 * the engine's vectors (B' in place of the style estimate, the target
 * guides, the same 8-bit planes and weights) through the search service,
 * with no uniformity penalty. energy = the mean of those distances divided
 * by the window's one-grey-level distance (usage.h's D1): the weighted mean
 * absolute difference per compared value, in grey levels.
 * Coverage: the share of source pixels that the best source patches of the
 * sampled target patches cover (pixels, not patch centres: a source patch
 * counts all its p x p pixels, as the engine's coverage does). */
typedef struct {
  double energy;
  double coverage;
  uint32_t samples;
  int step, patch; /* measured with: the sampling step, the patch size */
} ts_stylit_energy;

/* in: checked inputs (ts_stylit_check); image: B', the target's size with
 * the style's colour channels (any type; converted as the style is). */
int ts_stylit_energy_measure(const ts_stylit_params *p, const ts_image *const *in, const ts_image *image, int step,
                             ts_search *search, ts_stylit_energy *out, char *err);
/* Every problem with the scene (ts_stylit_check), the image to score (its
 * size and channels against the scene's) and the step, one per line: 0 or
 * TS_EINVAL. */
int ts_stylit_energy_check(const ts_stylit_params *p, const ts_image *const *in, const ts_image *image, int step,
                           char *msg, size_t len);

/* The energy engine (energy_engine.c): the measure as a job, so that it
 * runs on a cluster as stylize does. Its parameters: the scene's (patch,
 * guides, weights, max_pixels; stylize's other parameters keep their
 * defaults, unused) and the step; its inputs the scene's and then "image",
 * B'; its result the JSON line below, as energy.json. */
typedef struct {
  ts_stylit_params scene;
  int step; /* 1..TS_STYLIT_MAX_STEP (1) */
} ts_stylit_energy_params;

#define TS_STYLIT_MAX_STEP 65536

/* The energy as one JSON line, what `texsyn energy --json` prints:
 * {"energy": E, "coverage": C, "coverage_of": "exemplar pixels",
 *  "samples": N, "step": S, "patch_size": P} (E and C with 6 decimals).
 * The length, or TS_ETOOBIG. */
int ts_stylit_energy_json(const ts_stylit_energy *e, char *buf, size_t cap);
/* Reads such a line back (len bytes, not NUL-terminated; a client reads
 * the file a coordinator sent): 0, or TS_EFORMAT saying what is wrong. */
int ts_stylit_energy_json_read(const char *text, size_t len, ts_stylit_energy *e, char *err);

/* The error map (stylit_error.c): per output pixel of a finished run, the
 * guided distance of its patch in res->image (with the target guides) to
 * the exemplar patch res->nnf gave it, no uniformity penalty, divided by
 * the window's one-grey-level distance: the weighted mean absolute
 * difference per compared value, in grey levels, as the energy counts.
 * in: the run's (checked) inputs; out: the result's width x height floats.
 * 0 or TS_ENOMEM. */
int ts_stylit_error_map(const ts_stylit_params *p, const ts_image *const *in, const ts_stylit_result *res,
                        float *out, char *err);

/* Apply-nnf: out (8-bit, src's channels, tw x th) = the engine's vote of
 * src's channels through nnf (tw x th source patch centres, x, y pairs),
 * patch p. Every entry must be the centre of a patch inside src. */
int ts_stylit_apply_nnf(const uint32_t *nnf, int tw, int th, int patch, const ts_image *src, ts_image *out,
                        char *err);

#endif
