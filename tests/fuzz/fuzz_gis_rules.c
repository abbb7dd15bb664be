/* fuzz_gis_rules.c - libFuzzer target for the vector lines' rules parser
 * (common/gis_rules.c, gis.h's JSON form of ts_gis_line_rules), which
 * reads what a user's catalogue says. The input is the rules' text, not
 * NUL-terminated. Rules the parser accepts must hold what gis.h promises
 * (counts, values, widths, units, orders in range, names terminated,
 * matches unique and given exactly when there is a field); a refusal must
 * say where ("fuzz.json:LINE:COL: ..."), and leave the rules zeroed. Any
 * crash, sanitizer report or broken promise is a bug. Build and run:
 * make fuzz. */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "gis.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void check_name(const char *s, int needed) {
  size_t n = strnlen(s, TS_GIS_NAME_LEN);
  if (n == TS_GIS_NAME_LEN || (needed && n == 0)) abort();
}

static void check_rules(const ts_gis_line_rules *r) {
  if (r->nrule < 1 || r->nrule > TS_GIS_MAX_RULES) abort();
  check_name(r->layer, 0);
  check_name(r->field, 0);
  check_name(r->width_field, 0);
  int has_field = r->field[0] != '\0';
  if (!has_field && r->nrule != 1) abort();
  for (int i = 0; i < r->nrule; i++) {
    const ts_gis_line_rule *u = &r->rule[i];
    check_name(u->match, has_field);
    if (!has_field && u->match[0] != '\0') abort();
    if (u->value < 1 || !(u->width > 0 && u->width <= 1e4)) abort();
    if (u->unit != TS_GIS_UNIT_MAP && u->unit != TS_GIS_UNIT_PIXEL) abort();
    if (u->order < -1000 || u->order > 1000) abort();
    if (u->nhidden < 0 || u->nhidden > TS_GIS_MAX_HIDDEN) abort();
    for (int j = 0; j < u->nhidden; j++)
      for (int k = 0; k < j; k++)
        if (u->hidden_under[j] == u->hidden_under[k]) abort();
    for (int j = 0; j < i; j++)
      if (has_field && strcmp(r->rule[j].match, u->match) == 0) abort();
  }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  char err[TS_ERR_LEN];
  /* An exact-size copy, so reading one byte past the input is caught. */
  char *text = malloc(size ? size : 1);
  ts_gis_line_rules *r = malloc(sizeof(*r));
  if (text != NULL && r != NULL) {
    if (size) memcpy(text, data, size);
    int rc = ts_gis_line_rules_parse(text, size, "fuzz.json", r, err);
    if (rc == 0) {
      check_rules(r);
    } else {
      if (memchr(err, '\0', TS_ERR_LEN) == NULL || err[0] == '\0') abort();
      if (rc != TS_ENOMEM && strncmp(err, "fuzz.json:", 10) != 0) abort();
      if (r->nrule != 0 || r->field[0] != '\0') abort();
    }
  }
  free(r);
  free(text);
  return 0;
}
