/* param.c - see param.h. */
#include "param.h"

#include <math.h>
#include <string.h>

#include "engine.h"
#include "error.h"
#include "util.h"

#define FIELD(params, p, T) ((T *)((char *)(params) + (p)->offset))
#define CFIELD(params, p, T) ((const T *)((const char *)(params) + (p)->offset))

const ts_param *ts_param_find(const ts_param *t, const char *key) {
  for (; t->key != NULL; t++)
    if (strcmp(t->key, key) == 0) return t;
  return NULL;
}

const ts_param *ts_param_find_flag(const ts_param *t, const char *flag) {
  for (; t->key != NULL; t++)
    if (t->flag != NULL && strcmp(t->flag, flag) == 0) return t;
  return NULL;
}

int ts_param_count(const ts_param *t) {
  int n = 0;
  while (t[n].key != NULL) n++;
  return n;
}

static int has_range(const ts_param *p);
static int in_range(const ts_param *p, double v);

/* ---- one value ----------------------------------------------------------- */

static int parse_enum(const ts_param *p, const char *text, int *out) {
  for (int i = 0; p->names[i] != NULL; i++)
    if (strcmp(p->names[i], text) == 0) {
      *out = i;
      return 0;
    }
  return TS_EINVAL;
}

/* Parses text into the field; no message. */
static int parse_value(const ts_param *p, void *params, const char *text) {
  switch (p->type) {
  case TS_PARAM_INT: return ts_parse_int(text, -1000000000, 1000000000, FIELD(params, p, int));
  case TS_PARAM_U64: return ts_parse_u64(text, FIELD(params, p, uint64_t));
  case TS_PARAM_DOUBLE: {
    double v;
    if (ts_parse_double(text, &v) != 0 || !isfinite(v)) return TS_EINVAL;
    *FIELD(params, p, double) = v;
    return 0;
  }
  case TS_PARAM_FLAG: return ts_parse_int(text, 0, 1, FIELD(params, p, int));
  case TS_PARAM_SIZE: {
    int *wh = FIELD(params, p, int);
    return ts_parse_size(text, TS_OUTPUT_SIDE_MAX, &wh[0], &wh[1]) != 0 ? TS_EINVAL : 0;
  }
  case TS_PARAM_ENUM: return parse_enum(p, text, FIELD(params, p, int));
  case TS_PARAM_CUSTOM: return p->codec->parse(text, FIELD(params, p, char));
  }
  return TS_EINVAL;
}

/* What a value of p looks like, for a parse error. */
static void expect_text(const ts_param *p, char *buf, size_t cap) {
  switch (p->type) {
  case TS_PARAM_INT: snprintf(buf, cap, "a whole number"); break;
  case TS_PARAM_U64: snprintf(buf, cap, "a whole number >= 0"); break;
  case TS_PARAM_DOUBLE: snprintf(buf, cap, "a number"); break;
  case TS_PARAM_FLAG: snprintf(buf, cap, "0 or 1"); break;
  case TS_PARAM_SIZE: snprintf(buf, cap, "WxH with 1..%d each, e.g. 1024x1024", TS_OUTPUT_SIDE_MAX); break;
  case TS_PARAM_ENUM: {
    size_t at = 0;
    buf[0] = '\0';
    for (int i = 0; p->names[i] != NULL && at < cap; i++) {
      int k = snprintf(buf + at, cap - at, "%s%s", i == 0 ? "one of " : ", ", p->names[i]);
      if (k < 0) break;
      at += (size_t)k;
    }
    break;
  }
  case TS_PARAM_CUSTOM: snprintf(buf, cap, "%s", p->codec->expect); break;
  }
}

int ts_param_parse(const ts_param *p, void *params, const char *text, const char *what, char *err) {
  if (parse_value(p, params, text) == 0) return 0;
  char expect[160];
  expect_text(p, expect, sizeof(expect));
  return ts_error(err, TS_EINVAL, "%s %s: need %s", what, text, expect);
}

int ts_params_set(const ts_param *t, void *params, const char *key, const char *text) {
  const ts_param *p = ts_param_find(t, key);
  if (p == NULL || (p->flags & TS_PARAM_EMBEDDED)) return TS_ENOENT;
  /* A spec's value must also be in range: some bound what the engine
   * allocates or indexes (aerial's classes), before any check runs. */
  if (parse_value(p, params, text) != 0) return TS_EINVAL;
  return has_range(p) && !in_range(p, ts_param_number(p, params)) ? TS_EINVAL : 0;
}

void ts_params_default(const ts_param *t, void *params) {
  for (; t->key != NULL; t++)
    if (t->def != NULL) (void)parse_value(t, params, t->def);
}

void ts_param_format(const ts_param *p, const void *params, char *buf, size_t cap) {
  switch (p->type) {
  case TS_PARAM_INT: case TS_PARAM_FLAG: snprintf(buf, cap, "%d", *CFIELD(params, p, int)); break;
  case TS_PARAM_U64: snprintf(buf, cap, "%llu", (unsigned long long)*CFIELD(params, p, uint64_t)); break;
  case TS_PARAM_DOUBLE: snprintf(buf, cap, "%.17g", *CFIELD(params, p, double)); break;
  case TS_PARAM_SIZE: {
    const int *wh = CFIELD(params, p, int);
    snprintf(buf, cap, "%dx%d", wh[0], wh[1]);
    break;
  }
  case TS_PARAM_ENUM: {
    int v = *CFIELD(params, p, int);
    int n = 0;
    while (p->names[n] != NULL) n++;
    snprintf(buf, cap, "%s", v >= 0 && v < n ? p->names[v] : "?");
    break;
  }
  case TS_PARAM_CUSTOM: p->codec->format(CFIELD(params, p, char), buf, cap); break;
  }
}

/* The field's default, formatted as the field would be. */
static void default_text(const ts_param *p, char *buf, size_t cap) {
  ts_engine_params tmp;
  memset(&tmp, 0, sizeof(tmp));
  if (p->def != NULL) (void)parse_value(p, &tmp, p->def);
  ts_param_format(p, &tmp, buf, cap);
}

int ts_param_is_default(const ts_param *p, const void *params) {
  char now[256], def[256];
  ts_param_format(p, params, now, sizeof(now));
  default_text(p, def, sizeof(def));
  return strcmp(now, def) == 0;
}

double ts_param_number(const ts_param *p, const void *params) {
  switch (p->type) {
  case TS_PARAM_INT: case TS_PARAM_FLAG: case TS_PARAM_ENUM: return *CFIELD(params, p, int);
  case TS_PARAM_U64: return (double)*CFIELD(params, p, uint64_t);
  case TS_PARAM_DOUBLE: return *CFIELD(params, p, double);
  default: return 0;
  }
}

/* ---- the spec ------------------------------------------------------------ */

/* Whether an entry's group has a value off its default. */
static int group_used(const ts_param *t, int group, const void *params) {
  for (; t->key != NULL; t++)
    if (t->group == group && !ts_param_is_default(t, params)) return 1;
  return 0;
}

int ts_params_format(const ts_param *t, const void *params, char *buf, size_t cap) {
  size_t n = 0;
  for (const ts_param *p = t; p->key != NULL; p++) {
    if (p->flags & TS_PARAM_EMBEDDED) continue;
    if (p->group != 0 && !group_used(t, p->group, params)) continue;
    char v[256];
    ts_param_format(p, params, v, sizeof(v));
    int k = snprintf(buf + n, cap - n, "%s=%s\n", p->key, v);
    if (k < 0 || (size_t)k >= cap - n) return TS_ETOOBIG;
    n += (size_t)k;
  }
  return (int)n;
}

/* ---- ranges -------------------------------------------------------------- */

/* The range in --help ("odd, 3..41") or in a message ("an odd number in
 * 3..41"). */
static void range_text(const ts_param *p, int message, char *buf, size_t cap) {
  const char *odd = !(p->flags & TS_PARAM_ODD) ? "" : message ? "an odd number in " : "odd, ";
  if (p->flags & TS_PARAM_UNBOUNDED) snprintf(buf, cap, "0..2^64-1");
  else if ((p->flags & TS_PARAM_ODD) && p->min == 0) snprintf(buf, cap, "0 or odd 1..%.15g", p->max);
  else if (p->flags & TS_PARAM_ZERO_OFF) snprintf(buf, cap, "0: off, or %.15g..%.15g", p->min, p->max);
  else if (p->flags & TS_PARAM_MIN_OPEN) snprintf(buf, cap, "more than %.15g, at most %.15g", p->min, p->max);
  else snprintf(buf, cap, "%s%.15g..%.15g", odd, p->min, p->max);
}

static int has_range(const ts_param *p) {
  return p->type == TS_PARAM_U64 || p->type == TS_PARAM_INT || p->type == TS_PARAM_DOUBLE;
}

static int in_range(const ts_param *p, double v) {
  if (p->flags & TS_PARAM_UNBOUNDED) return 1;
  if ((p->flags & TS_PARAM_ZERO_OFF) && v == 0) return 1;
  if (p->flags & TS_PARAM_MIN_OPEN ? !(v > p->min) : !(v >= p->min)) return 0;
  if (!(v <= p->max)) return 0;
  return !(p->flags & TS_PARAM_ODD) || fmod(v, 2.0) != 0.0 || v == 0;
}

void ts_params_check(const ts_param *t, const void *params, char *msg, size_t len, int *n) {
  for (; t->key != NULL; t++) {
    if (!has_range(t) || in_range(t, ts_param_number(t, params))) continue;
    char v[64], range[96];
    if (t->type == TS_PARAM_DOUBLE) snprintf(v, sizeof(v), "%g", ts_param_number(t, params));
    else ts_param_format(t, params, v, sizeof(v));
    range_text(t, 1, range, sizeof(range));
    if (t->flag != NULL) ts_problem(msg, len, n, "--%s %s: need %s", t->flag, v, range);
    else ts_problem(msg, len, n, "%s=%s: need %s", t->key, v, range);
  }
}

/* ---- --help -------------------------------------------------------------- */

enum { HELP_INDENT = 23, HELP_WIDTH = 79 };

void ts_help_line(FILE *f, const char *option, const char *text) {
  int col = fprintf(f, "  %s", option);
  if (col >= HELP_INDENT - 1) {
    fputc('\n', f);
    col = 0;
  }
  const char *s = text;
  while (*s != '\0') {
    fprintf(f, "%*s", HELP_INDENT - col, "");
    col = HELP_INDENT;
    /* As many words as fit (at least one). */
    const char *end = s, *fit = NULL;
    while (*end != '\0') {
      const char *w = end;
      while (*w == ' ') w++;
      while (*w != '\0' && *w != ' ') w++;
      if (fit != NULL && col + (w - s) > HELP_WIDTH) break;
      fit = end = w;
    }
    fprintf(f, "%.*s\n", (int)(end - s), s);
    col = 0;
    s = end;
    while (*s == ' ') s++;
  }
  if (text[0] == '\0') fputc('\n', f);
}

/* The help text, then in brackets the range and the default:
 * "pyramid levels (1..12; default 5)". */
static void entry_text(const ts_param *p, char *buf, size_t cap) {
  char range[96] = "", def[128] = "";
  if (has_range(p)) range_text(p, 0, range, sizeof(range));
  else if (p->type == TS_PARAM_ENUM) {
    size_t at = 0;
    for (int i = 0; p->names[i] != NULL && at < sizeof(range); i++) {
      int k = snprintf(range + at, sizeof(range) - at, "%s%s", i == 0 ? "" : "|", p->names[i]);
      if (k < 0) break;
      at += (size_t)k;
    }
  }
  if (p->def_help != NULL) snprintf(def, sizeof(def), "default %s", p->def_help);
  else if (p->type == TS_PARAM_FLAG) snprintf(def, sizeof(def), "default off");
  else if (p->def != NULL) snprintf(def, sizeof(def), "default %s", p->def);
  const char *sep = range[0] && def[0] ? "; " : "";
  if (range[0] || def[0]) snprintf(buf, cap, "%s (%s%s%s)", p->help, range, sep, def);
  else snprintf(buf, cap, "%s", p->help);
}

static const char *default_for(const ts_param_default *d, const char *key) {
  for (; d != NULL && d->key != NULL; d++)
    if (strcmp(d->key, key) == 0) return d->value;
  return NULL;
}

void ts_params_help(FILE *f, const ts_param *t, const ts_param_default *defaults) {
  for (; t->key != NULL; t++) {
    if (t->flag == NULL) continue;
    char option[64], text[1024];
    snprintf(option, sizeof(option), "--%s%s%s", t->flag, t->arg ? " " : "", t->arg ? t->arg : "");
    ts_param shown = *t;
    const char *own = default_for(defaults, t->key);
    if (own != NULL) shown.def = own, shown.def_help = NULL;
    entry_text(&shown, text, sizeof(text));
    ts_help_line(f, option, text);
  }
}
