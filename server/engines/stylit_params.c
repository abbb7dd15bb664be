/* stylit_params.c - the parameters of a stylization (stylit.h), declared
 * once (param.h): the scene's (shared with the energy engine) and the
 * synthesis's; the search value's text form; the guides' weights. */
#include <stddef.h>
#include <stdio.h>
#include <string.h>

#include "error.h"
#include "param.h"
#include "stylit.h"

static const char *const kSearchNames[] = {"exact", "patchmatch", "auto", "size"};

const char *ts_stylit_search_name(int mode) {
  return mode >= TS_STYLIT_EXACT && mode <= TS_STYLIT_SIZE ? kSearchNames[mode] : "unknown";
}

static int mode_of(const char *name, size_t len, int last) {
  for (int m = TS_STYLIT_EXACT; m <= last; m++)
    if (strlen(kSearchNames[m]) == len && strncmp(name, kSearchNames[m], len) == 0) return m;
  return -1;
}

int ts_stylit_search_parse(const char *text, ts_stylit_params *p, char *err) {
  int m = mode_of(text, strlen(text), TS_STYLIT_SIZE);
  if (m >= 0) {
    p->search = m;
    p->nlevel_modes = 0;
    return 0;
  }
  int n = 0;
  for (const char *s = text;; n++) {
    const char *comma = strchr(s, ',');
    size_t len = comma != NULL ? (size_t)(comma - s) : strlen(s);
    int lm = n < TS_STYLIT_MAX_LEVELS ? mode_of(s, len, TS_STYLIT_PATCHMATCH) : -1;
    if (lm < 0)
      return ts_error(err, TS_EINVAL, "--search %s: need exact, patchmatch, size, auto, or a list of exact and patchmatch "
                      "with one per level, coarsest first (at most %d)", text, TS_STYLIT_MAX_LEVELS);
    p->level_mode[n] = (uint8_t)lm;
    if (comma == NULL) break;
    s = comma + 1;
  }
  p->search = TS_STYLIT_LIST;
  p->nlevel_modes = n + 1;
  return 0;
}

void ts_stylit_search_format(const ts_stylit_params *p, char *out, size_t cap) {
  if (p->search != TS_STYLIT_LIST) {
    snprintf(out, cap, "%s", ts_stylit_search_name(p->search));
    return;
  }
  size_t o = 0;
  out[0] = '\0';
  for (int l = 0; l < p->nlevel_modes && o < cap; l++) {
    int n = snprintf(out + o, cap - o, "%s%s", l ? "," : "", ts_stylit_search_name(p->level_mode[l]));
    o += n > 0 ? (size_t)n : 0;
  }
}

double ts_stylit_weight(const ts_stylit_params *p, int k) {
  return p->weight[k] < 0 ? 1.0 / p->guides : p->weight[k];
}

/* The search value as a CUSTOM field: it sets the mode and the per-level
 * list beside it, so the codec reaches the whole struct. */
static ts_stylit_params *of_search(void *field) {
  return (ts_stylit_params *)((char *)field - offsetof(ts_stylit_params, search));
}
static int search_parse(const char *text, void *field) { return ts_stylit_search_parse(text, of_search(field), NULL); }
static void search_format(const void *field, char *buf, size_t cap) {
  ts_stylit_search_format((const ts_stylit_params *)((const char *)field - offsetof(ts_stylit_params, search)), buf,
                          cap);
}
const ts_param_codec ts_stylit_search_codec = {
    search_parse, search_format, "exact, patchmatch, size, auto, or a list of exact and patchmatch with one per level"};

#define F(field) offsetof(ts_stylit_params, field)

/* In the spec's order; the guides' weights (weight_K) follow them. */
const ts_param ts_stylit_param_table[] = {
    TS_STYLIT_SCENE_PARAMS(0),
    {"levels", "levels", "L", TS_PARAM_INT, F(levels), 0, TS_STYLIT_MAX_LEVELS, "0", "pyramid levels",
     "as many as leave 4 patches on each side of the coarsest level, at most 6"},
    {"iters", "iters", "K", TS_PARAM_INT, F(iters), 1, 100, "6", "search-and-vote iterations per level"},
    {"uniformity", "uniformity", "U", TS_PARAM_DOUBLE, F(uniformity), 0, 1000, "1",
     "how much a source patch used more than its share costs, 0 = off: U = 1 charges a patch used at the "
     "average rate one grey level per compared value"},
    {"seed", "seed", "S", TS_PARAM_U64, F(seed), 0, 0, "1",
     "seed of the coarsest level's random start and of the patchmatch passes", .flags = TS_PARAM_UNBOUNDED},
    {"search", "search", "MODE", TS_PARAM_CUSTOM, F(search), 0, 0, "size",
     "exact: every target patch takes the best source patch; patchmatch: passes of propagation and random "
     "search over fixed seeded tiles (approximate; the same bytes on any pool); size: exact at each level whose "
     "exact search takes at most --budget at a fixed reference speed (1e9 comparisons a second), patchmatch at "
     "the others: the same bytes on any pool; auto (opt-in): the same at the calibrated speed of the threads or "
     "the pool, so its bytes depend on the pool; the report's search.levels says which ran where; or a list of "
     "exact and patchmatch, one per level, coarsest first (that list: the same job on any pool)",
     .codec = &ts_stylit_search_codec},
    {"pm_iters", "pm-iters", "N", TS_PARAM_INT, F(pm_iters), 1, 100, "4", "patchmatch passes per search step"},
    {"budget", "budget", "SECONDS", TS_PARAM_DOUBLE, F(budget), 0, 1e6, "1",
     "size, auto: the longest an exact level may take"},
    {"scale", "scale", "F", TS_PARAM_DOUBLE, F(scale), 0, 1, "1",
     "work at this fraction of the inputs' size: the style and every guide resampled (area average) first, the "
     "output and --nnf at the scaled target size and exemplar; for a preview of a large scene",
     .group = 1, .flags = TS_PARAM_MIN_OPEN},
    {NULL}};

void ts_stylit_params_default(ts_stylit_params *p) {
  memset(p, 0, sizeof(*p));
  ts_params_default(ts_stylit_param_table, p);
  for (int k = 0; k < TS_STYLIT_MAX_GUIDES; k++) p->weight[k] = -1.0; /* 1 / guides */
}
