/* suggest.h - "did you mean": the known word closest to a mistyped one,
 * for commands, options and catalogue keys alike. */
#ifndef TS_SUGGEST_H
#define TS_SUGGEST_H

#include <getopt.h>
#include <stddef.h>

/* The one of the n known words within two edits (insertions, deletions,
 * substitutions, swaps of neighbours) of the first len bytes of word and
 * closest to it; the first such on a tie; NULL if none. */
const char *ts_closest(const char *word, size_t len, const char *const *known, size_t n);

/* The message for what getopt_long returned '?' or ':' for: arg (as given,
 * argv[optind - 1]) is an option of longopts missing its value, or an
 * unknown option, with the closest long option if there is one. TS_EINVAL;
 * the message ends with "(see texsyn CMD --help)". */
int ts_arg_unknown(const char *cmd, const char *arg, const struct option *longopts, char *err);

#endif
