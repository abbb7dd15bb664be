/* gis_rules.c - ts_gis_line_rules_parse (gis.h): the vector lines' rules
 * from their JSON form, walked from json.h's DOM so that every refusal
 * points at the value at fault. No GDAL here: the rules come from the
 * catalogue, a file a user hands in, and are checked before anything is
 * loaded (tests/fuzz/fuzz_gis_rules.c). */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <string.h>

#include "error.h"
#include "gis.h"
#include "json.h"

/* Far more values than 64 rules of 5 fields need. */
#define MAX_NODES 2048

typedef struct {
  const ts_json_doc *doc;
  char *err;
  char what[48];              /* "the line rules", "rule 3" */
  const char *const *caller;  /* keys of the rules' object that its embedder reads, or NULL */
} reader;

/* "NAME:LINE:COL: WHAT: message" at node's value (its key, if key_pos). */
__attribute__((format(printf, 4, 5))) static int bad_at(reader *r, int node, int key_pos, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  int rc = ts_json_error_at(r->doc, node, key_pos, r->what, r->err, fmt, ap);
  va_end(ap);
  return rc;
}
#define bad(r, node, ...) bad_at(r, node, 0, __VA_ARGS__)

/* "got VALUE" with the value as the text gives it. */
static const char *got(const reader *r, int node, char *buf, size_t cap) {
  char q[48];
  ts_json_quote(r->doc, node, q, sizeof(q));
  snprintf(buf, cap, "got %s", q);
  return buf;
}

static int key_in(const ts_json_node *n, const char *const *keys) {
  for (size_t i = 0; keys != NULL && keys[i] != NULL; i++)
    if (strlen(keys[i]) == n->klen && memcmp(keys[i], n->key, n->klen) == 0) return 1;
  return 0;
}

/* Every member of obj has a key in known, or in extra (the embedder's, may
 * be NULL). */
static int only_known_keys(reader *r, int obj, const char *const *known, const char *const *extra, const char *list) {
  const ts_json_node *nodes = r->doc->nodes;
  for (int m = nodes[obj].first; m >= 0; m = nodes[m].next)
    if (!key_in(&nodes[m], known) && !key_in(&nodes[m], extra))
      return bad_at(r, m, 1, "unknown key \"%.40s\" (known: %s)", nodes[m].key, list);
  return 0;
}

/* A string member of 1..TS_GIS_NAME_LEN-1 bytes without NULs into out
 * ("" if absent and optional). */
static int name_member(reader *r, int obj, const char *key, int needed, char out[TS_GIS_NAME_LEN]) {
  int m = ts_json_member(r->doc, obj, key);
  out[0] = '\0';
  if (m < 0) return needed ? bad(r, obj, "\"%s\" is required", key) : 0;
  const ts_json_node *n = &r->doc->nodes[m];
  char g[80];
  if (n->type != TS_JSON_STRING || n->slen == 0 || n->slen >= TS_GIS_NAME_LEN || memchr(n->str, '\0', n->slen))
    return bad(r, m, "\"%s\" must be a string of 1..%d bytes, %s", key, TS_GIS_NAME_LEN - 1, got(r, m, g, sizeof(g)));
  memcpy(out, n->str, n->slen + 1);
  return 0;
}

/* A number member within [lo, hi] (whole if whole), def if absent. */
static int number_member(reader *r, int obj, const char *key, double lo, double hi, int whole, int needed, double def,
                         double *out) {
  int m = ts_json_member(r->doc, obj, key);
  *out = def;
  if (m < 0) return needed ? bad(r, obj, "\"%s\" is required", key) : 0;
  const ts_json_node *n = &r->doc->nodes[m];
  char g[80];
  if (n->type != TS_JSON_NUMBER || !(n->num >= lo && n->num <= hi) || (whole && n->num != floor(n->num)))
    return bad(r, m, "\"%s\" must be %s %g..%g, %s", key, whole ? "a whole number" : "a number", lo, hi,
               got(r, m, g, sizeof(g)));
  *out = n->num;
  return 0;
}

static int read_unit(reader *r, int obj, ts_gis_unit *unit) {
  int m = ts_json_member(r->doc, obj, "unit");
  *unit = TS_GIS_UNIT_MAP;
  if (m < 0) return 0;
  const ts_json_node *n = &r->doc->nodes[m];
  char g[80];
  if (n->type == TS_JSON_STRING && strcmp(n->str, "map") == 0 && n->slen == 3) return 0;
  if (n->type == TS_JSON_STRING && strcmp(n->str, "px") == 0 && n->slen == 2) {
    *unit = TS_GIS_UNIT_PIXEL;
    return 0;
  }
  return bad(r, m, "\"unit\" must be \"map\" (the CRS's units, metres for UTM) or \"px\", %s", got(r, m, g, sizeof(g)));
}

/* "hidden_under": 0..TS_GIS_MAX_HIDDEN distinct class ids. */
static int read_hidden(reader *r, int obj, ts_gis_line_rule *u) {
  int list = ts_json_member(r->doc, obj, "hidden_under");
  if (list < 0) return 0;
  const ts_json_node *n = &r->doc->nodes[list];
  char g[80];
  if (n->type != TS_JSON_ARRAY || n->count > TS_GIS_MAX_HIDDEN)
    return bad(r, list, "\"hidden_under\" must be an array of at most %d class ids, %s", TS_GIS_MAX_HIDDEN,
               got(r, list, g, sizeof(g)));
  for (int m = n->first; m >= 0; m = r->doc->nodes[m].next) {
    const ts_json_node *c = &r->doc->nodes[m];
    if (c->type != TS_JSON_NUMBER || !(c->num >= 0 && c->num <= 65535) || c->num != floor(c->num))
      return bad(r, m, "\"hidden_under\" holds class ids, whole numbers 0..65535, %s", got(r, m, g, sizeof(g)));
    for (int j = 0; j < u->nhidden; j++)
      if (u->hidden_under[j] == (uint16_t)c->num) return bad(r, m, "class %d is given twice", (int)c->num);
    u->hidden_under[u->nhidden++] = (uint16_t)c->num;
  }
  return 0;
}

static int read_rule(reader *r, int obj, int i, int has_field, ts_gis_line_rules *out) {
  static const char *const known[] = {"match", "value", "width", "unit", "order", "hidden_under", NULL};
  snprintf(r->what, sizeof(r->what), "line rule %d", i + 1);
  char g[80];
  if (r->doc->nodes[obj].type != TS_JSON_OBJECT) return bad(r, obj, "must be an object, %s", got(r, obj, g, sizeof(g)));
  ts_gis_line_rule *u = &out->rule[i];
  double value, order;
  int rc = only_known_keys(r, obj, known, NULL,
                           "\"match\", \"value\", \"width\", \"unit\", \"order\", \"hidden_under\"");
  if (rc == 0 && !has_field && ts_json_member(r->doc, obj, "match") >= 0)
    return bad(r, ts_json_member(r->doc, obj, "match"), "\"match\" needs a \"field\" to match against");
  if (rc == 0) rc = name_member(r, obj, "match", has_field, u->match);
  if (rc == 0) rc = number_member(r, obj, "value", 1, 255, 1, 1, 0, &value);
  if (rc == 0) rc = number_member(r, obj, "width", 0, 1e4, 0, 1, 0, &u->width);
  if (rc == 0 && u->width <= 0) return bad(r, ts_json_member(r->doc, obj, "width"), "\"width\" must be above 0");
  if (rc == 0) rc = read_unit(r, obj, &u->unit);
  if (rc == 0) rc = number_member(r, obj, "order", -1000, 1000, 1, 0, 0, &order);
  if (rc == 0) rc = read_hidden(r, obj, u);
  if (rc != 0) return rc;
  u->value = (uint8_t)value;
  u->order = (int)order;
  for (int j = 0; j < i; j++)
    if (has_field && strcmp(out->rule[j].match, u->match) == 0)
      return bad(r, ts_json_member(r->doc, obj, "match"), "\"match\" \"%s\" is rule %d's too", u->match, j + 1);
  return 0;
}

static int read_rules(reader *r, int obj, ts_gis_line_rules *out) {
  static const char *const known[] = {"layer", "field", "width_field", "rules", NULL};
  char g[80];
  if (r->doc->nodes[obj].type != TS_JSON_OBJECT) return bad(r, obj, "must be an object, %s", got(r, obj, g, sizeof(g)));
  int rc = only_known_keys(r, obj, known, r->caller, "\"layer\", \"field\", \"width_field\", \"rules\"");
  if (rc == 0) rc = name_member(r, obj, "layer", 0, out->layer);
  if (rc == 0) rc = name_member(r, obj, "field", 0, out->field);
  if (rc == 0) rc = name_member(r, obj, "width_field", 0, out->width_field);
  if (rc != 0) return rc;
  int list = ts_json_member(r->doc, obj, "rules");
  if (list < 0) return bad(r, obj, "\"rules\" is required");
  const ts_json_node *n = &r->doc->nodes[list];
  if (n->type != TS_JSON_ARRAY || n->count < 1 || n->count > TS_GIS_MAX_RULES)
    return bad(r, list, "\"rules\" must be an array of 1..%d rules, %s", TS_GIS_MAX_RULES, got(r, list, g, sizeof(g)));
  int has_field = out->field[0] != '\0';
  if (!has_field && n->count != 1)
    return bad(r, list, "%d rules but no \"field\" to choose between them: give one rule, or a field", n->count);
  int i = 0;
  for (int m = n->first; m >= 0; m = r->doc->nodes[m].next, i++)
    if ((rc = read_rule(r, m, i, has_field, out)) != 0) return rc;
  out->nrule = n->count;
  return 0;
}

int ts_gis_line_rules_read(const ts_json_doc *doc, int obj, const char *const *caller_keys, ts_gis_line_rules *out,
                           char *err) {
  memset(out, 0, sizeof(*out));
  reader r = {doc, err, "the line rules", caller_keys};
  int rc = read_rules(&r, obj, out);
  if (rc != 0) memset(out, 0, sizeof(*out));
  return rc;
}

int ts_gis_line_rules_parse(const char *text, size_t len, const char *name, ts_gis_line_rules *out, char *err) {
  memset(out, 0, sizeof(*out));
  ts_json_doc doc;
  int rc = ts_json_parse(&doc, name, text, len, MAX_NODES, err);
  if (rc != 0) return rc;
  rc = ts_gis_line_rules_read(&doc, 0, NULL, out, err);
  ts_json_free(&doc);
  return rc;
}

void ts_gis_lines_hide(const ts_gis_line_rules *rules, const uint16_t *ids, uint8_t *lines, size_t n) {
  const ts_gis_line_rule *hiding[TS_GIS_MAX_RULES]; /* the rules hiding their lines somewhere */
  int nh = 0;
  for (int i = 0; i < rules->nrule && i < TS_GIS_MAX_RULES; i++)
    if (rules->rule[i].nhidden > 0) hiding[nh++] = &rules->rule[i];
  for (size_t p = 0; nh > 0 && p < n; p++)
    for (int k = 0; lines[p] != 0 && k < nh; k++) {
      if (hiding[k]->value != lines[p]) continue;
      for (int j = 0; j < hiding[k]->nhidden; j++)
        if (hiding[k]->hidden_under[j] == ids[p]) {
          lines[p] = 0;
          break;
        }
    }
}
