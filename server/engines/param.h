/* param.h - an engine's parameters, each declared once.
 *
 * An engine lists its parameters in one table (as ffmpeg's AVOption tables
 * do): the job spec key, the command-line flag, the type and the field in
 * the engine's parameter struct, the range, the default and the help.
 * Everything else is derived from that line: the struct's defaults, the
 * spec's parsing and writing (server and spool), range errors, the CLI's
 * options and its --help, and so the manual pages generated from --help.
 * Adding a parameter is one line in one table, plus the code that uses it.
 *
 * Checks that relate several parameters, or parameters and inputs (a
 * neighbourhood wider than the block, levels that fit the output), stay
 * in the engine's check: the table holds what one value alone must be. */
#ifndef TS_PARAM_H
#define TS_PARAM_H

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>

typedef enum {
  TS_PARAM_INT,    /* int */
  TS_PARAM_U64,    /* uint64_t */
  TS_PARAM_DOUBLE, /* double, written with 17 significant digits (round-trips) */
  TS_PARAM_FLAG,   /* int 0 or 1; on the command line an option without value */
  TS_PARAM_SIZE,   /* two ints, width then height: "WxH" */
  TS_PARAM_ENUM,   /* int: the index of its value in `names` */
  TS_PARAM_CUSTOM  /* the field's own parse and format (codec) */
} ts_param_type;

enum {
  TS_PARAM_ODD = 1,       /* INT: odd values only */
  TS_PARAM_MIN_OPEN = 2,  /* INT, DOUBLE: min itself excluded */
  TS_PARAM_UNBOUNDED = 4, /* U64: any value (min and max unused) */
  TS_PARAM_EMBEDDED = 8,  /* a command-line setting the spec does not keep:
                             the job runs in-process only */
  TS_PARAM_NEGATE = 16,   /* FLAG: the option sets 0 (--no-self for self=1) */
  TS_PARAM_ZERO_OFF = 32, /* DOUBLE: 0 too, meaning off (a guide's weight:
                             "0 (off) or 0.01..100") */
};

/* A CUSTOM field's text form. */
typedef struct {
  int (*parse)(const char *text, void *field); /* 0 or TS_EINVAL */
  void (*format)(const void *field, char *buf, size_t cap);
  const char *expect; /* what a value looks like, for errors */
} ts_param_codec;

typedef struct {
  const char *key;    /* job spec key, e.g. "usage_weight"; NULL ends a table */
  const char *flag;   /* long option without "--", e.g. "usage-weight"; NULL: the spec only */
  const char *arg;    /* the value's name in --help ("N", "WxH"); NULL for FLAG */
  ts_param_type type;
  size_t offset;      /* of the field in the engine's parameter struct */
  double min, max;    /* INT, U64, DOUBLE: the range, inclusive (see flags) */
  const char *def;    /* the default as spec text; NULL: none (zero until given) */
  const char *help;   /* what it is and does; --help adds the range and the default */
  /* --help's "(default ...)" when the default value means something else
   * ("all but the finest two"); NULL: def, or "off" for a FLAG. */
  const char *def_help;
  /* 0: always in the spec. Otherwise the parameters of one group are
   * written only when one of them differs from its default: a job that
   * does not use an option keeps the spec text (and so the checkpoint tag)
   * it had before the option existed. */
  int group;
  unsigned flags;
  const char *const *names;    /* ENUM: the values' names, NULL-terminated */
  const ts_param_codec *codec; /* CUSTOM */
} ts_param;

/* The entry of `key` (spec) or of `flag` (command line), or NULL. */
const ts_param *ts_param_find(const ts_param *table, const char *key);
const ts_param *ts_param_find_flag(const ts_param *table, const char *flag);
/* Number of entries. */
int ts_param_count(const ts_param *table);

/* Sets every field of the table to its default (the others untouched). */
void ts_params_default(const ts_param *table, void *params);
/* Sets one field from text: 0, or TS_EINVAL with a message naming `what`
 * ("--levels", "levels") and what a value looks like. The type is checked
 * here, the range by ts_params_check. */
int ts_param_parse(const ts_param *p, void *params, const char *text, const char *what, char *err);
/* Sets spec key `key`: 0, TS_EINVAL (not of the type, or out of range),
 * or TS_ENOENT if the table lacks it or it is EMBEDDED. */
int ts_params_set(const ts_param *table, void *params, const char *key, const char *text);
/* Appends the spec lines `key=value\n` in table order (groups as above);
 * the length, or TS_ETOOBIG. */
int ts_params_format(const ts_param *table, const void *params, char *buf, size_t cap);
/* The value of one field as spec text. */
void ts_param_format(const ts_param *p, const void *params, char *buf, size_t cap);
/* Whether a field holds its default. */
int ts_param_is_default(const ts_param *p, const void *params);
/* The field as a number (INT, U64, DOUBLE, FLAG, ENUM; 0 otherwise). */
double ts_param_number(const ts_param *p, const void *params);
/* Appends a problem line (ts_problem) for each field outside its range,
 * naming it by its flag ("--refine 25: need 0..20"). */
void ts_params_check(const ts_param *table, const void *params, char *msg, size_t len, int *n);

/* A command's own default for a parameter of its engine, as ffmpeg's
 * per-codec defaults override an AVOption's: the parameter stays declared
 * once, in the engine's table, and the command names the value it starts
 * from (texsyn video's search budget: a sequence pays it on every frame).
 * A list ends with a NULL key. */
typedef struct {
  const char *key, *value; /* spec key and spec text */
} ts_param_default;

/* The help lines of the table's flags, as --help prints them; defaults
 * (NULL: none) replaces the default shown for the keys it names. */
void ts_params_help(FILE *f, const ts_param *table, const ts_param_default *defaults);
/* One option's help line(s): "  --flag ARG" then the text, wrapped. */
void ts_help_line(FILE *f, const char *option, const char *text);

#endif
