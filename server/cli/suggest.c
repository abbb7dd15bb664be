/* suggest.c - see suggest.h. */
#include "suggest.h"

#include <string.h>

#include "error.h"

/* Edit distance with adjacent transpositions (optimal string alignment),
 * for suggesting a known word for a typo such as "usage_wieght". Words
 * longer than 31 bytes are never close to a known one. */
static int edit_distance(const char *a, size_t na, const char *b) {
  size_t nb = strlen(b);
  if (na > 31 || nb > 31) return 99;
  int d[32][32];
  for (size_t i = 0; i <= na; i++) d[i][0] = (int)i;
  for (size_t j = 0; j <= nb; j++) d[0][j] = (int)j;
  for (size_t i = 1; i <= na; i++) {
    for (size_t j = 1; j <= nb; j++) {
      int cost = a[i - 1] != b[j - 1];
      int v = d[i - 1][j] + 1;
      if (d[i][j - 1] + 1 < v) v = d[i][j - 1] + 1;
      if (d[i - 1][j - 1] + cost < v) v = d[i - 1][j - 1] + cost;
      if (i > 1 && j > 1 && a[i - 1] == b[j - 2] && a[i - 2] == b[j - 1] && d[i - 2][j - 2] + 1 < v)
        v = d[i - 2][j - 2] + 1;
      d[i][j] = v;
    }
  }
  return d[na][nb];
}

const char *ts_closest(const char *word, size_t len, const char *const *known, size_t n) {
  const char *best = NULL;
  int best_d = 3; /* within two edits */
  for (size_t i = 0; i < n; i++) {
    int d = edit_distance(word, len, known[i]);
    if (d < best_d) {
      best_d = d;
      best = known[i];
    }
  }
  return best;
}

#define MAX_LONGOPTS 256

/* A short option getopt stopped at (optopt): known (a long option has it
 * as its value) means its value is missing. Inside a cluster ("-xvf")
 * argv[optind - 1] is not the option's word, so the message names the
 * letter alone. */
static int short_unknown(const char *cmd, const struct option *longopts, char *err) {
  for (size_t i = 0; longopts[i].name != NULL; i++)
    if (longopts[i].val == optopt)
      return ts_error(err, TS_EINVAL, "-%c needs a value (see texsyn %s --help)", optopt, cmd);
  return ts_error(err, TS_EINVAL, "unknown option -%c (see texsyn %s --help)", optopt, cmd);
}

int ts_arg_unknown(const char *cmd, const char *arg, const struct option *longopts, char *err) {
  if (!(arg[0] == '-' && arg[1] == '-') && optopt > 0 && optopt < 256) return short_unknown(cmd, longopts, err);
  const char *name = arg + strspn(arg, "-");
  size_t len = strcspn(name, "=");
  const char *names[MAX_LONGOPTS];
  size_t n = 0;
  for (; longopts[n].name != NULL && n < MAX_LONGOPTS; n++) {
    names[n] = longopts[n].name;
    if (strlen(names[n]) == len && strncmp(names[n], name, len) == 0)
      return ts_error(err, TS_EINVAL, "--%s %s (see texsyn %s --help)", names[n],
                      longopts[n].has_arg == no_argument ? "takes no value" : "needs a value", cmd);
  }
  const char *best = name[0] != '\0' ? ts_closest(name, len, names, n) : NULL;
  if (best != NULL)
    return ts_error(err, TS_EINVAL, "unknown option %s; did you mean --%s? (see texsyn %s --help)", arg, best, cmd);
  return ts_error(err, TS_EINVAL, "unknown option %s (see texsyn %s --help)", arg, cmd);
}
