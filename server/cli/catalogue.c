/* catalogue.c - see catalogue.h. The JSON is read whole into a DOM
 * (common/json.h); this file only walks it and checks each field, so every
 * message can point at the value at fault. */
#include "catalogue.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "error.h"
#include "gis.h"
#include "json.h"
#include "suggest.h"
#include "util.h"

/* More values than any catalogue within the limits needs (64 classes of 5
 * fields and 256 colours of 3 numbers are under 1,500), so a huge file is
 * refused quickly rather than walked. */
#define TS_CAT_MAX_NODES 16384

static const char *const kind_names[] = {"stochastic", "structured"};

const char *ts_cat_kind_name(ts_cat_kind kind) {
  return kind == TS_CAT_STRUCTURED ? kind_names[1] : kind_names[0];
}

typedef struct {
  const ts_json_doc *doc;
  const char *base_dir;
  ts_catalogue *cat;
  char *err;
  char what[96]; /* the object being read, e.g. `class 2 ("town")` */
} reader;

/* "NAME:LINE:COL: WHAT: message" at node's value (its key, if key_pos). */
__attribute__((format(printf, 4, 5))) static int bad(reader *r, int node, int key_pos, const char *fmt, ...) {
  va_list ap;
  va_start(ap, fmt);
  int rc = ts_json_error_at(r->doc, node, key_pos, r->what, r->err, fmt, ap);
  va_end(ap);
  return rc;
}

/* "got VALUE" for a message about node, VALUE as the file gives it. */
static const char *got(const reader *r, int node, char *buf, size_t cap) {
  char q[48];
  ts_json_quote(r->doc, node, q, sizeof(q));
  snprintf(buf, cap, "got %s", q);
  return buf;
}

/* --- unknown keys ---------------------------------------------------------- */

/* Every member of obj has a key in known (NULL-terminated); else the first
 * other one is named, with the closest known key if it looks like a typo. */
static int only_known_keys(reader *r, int obj, const char *const *known) {
  const ts_json_node *nodes = r->doc->nodes;
  for (int m = nodes[obj].first; m >= 0; m = nodes[m].next) {
    size_t i;
    for (i = 0; known[i] != NULL; i++)
      if (strlen(known[i]) == nodes[m].klen && memcmp(known[i], nodes[m].key, nodes[m].klen) == 0) break;
    if (known[i] != NULL) continue;
    char list[128] = "";
    for (i = 0; known[i] != NULL; i++)
      snprintf(list + strlen(list), sizeof(list) - strlen(list), "%s\"%s\"", i ? ", " : "", known[i]);
    const char *best = ts_closest(nodes[m].key, nodes[m].klen, known, i);
    char hint[64] = "";
    if (best != NULL) snprintf(hint, sizeof(hint), "; did you mean \"%s\"?", best);
    return bad(r, m, 1, "unknown key \"%.40s\" (known: %s)%s", nodes[m].key, list, hint);
  }
  return 0;
}

/* --- fields ------------------------------------------------------------------ */

/* The member key of obj, required: its node, or an error at obj. */
static int required(reader *r, int obj, const char *key, const char *expect, int *node) {
  *node = ts_json_member(r->doc, obj, key);
  if (*node < 0) return bad(r, obj, 0, "no \"%s\" (%s)", key, expect);
  return 0;
}

/* A whole number lo..hi. */
static int whole_number(reader *r, int node, const char *field, long lo, long hi, long *out) {
  const ts_json_node *n = &r->doc->nodes[node];
  char g[64];
  if (n->type != TS_JSON_NUMBER || n->num != floor(n->num) || n->num < (double)lo || n->num > (double)hi)
    return bad(r, node, 0, "%s must be a whole number %ld..%ld, %s", field, lo, hi, got(r, node, g, sizeof(g)));
  *out = (long)n->num;
  return 0;
}

/* A string of 1..max_len bytes without control characters (so a \u0000
 * cannot cut a name or path short, nor a \u001b reach a terminal). */
static int text_value(reader *r, int node, const char *field, const char *expect, size_t max_len) {
  const ts_json_node *n = &r->doc->nodes[node];
  char g[64];
  if (n->type != TS_JSON_STRING || n->slen == 0)
    return bad(r, node, 0, "%s must be %s, %s", field, expect, got(r, node, g, sizeof(g)));
  if (n->slen > max_len) return bad(r, node, 0, "%s is %zu bytes long (at most %zu)", field, n->slen, max_len);
  for (size_t i = 0; i < n->slen; i++) {
    unsigned char c = (unsigned char)n->str[i];
    if (c < 0x20 || c == 0x7F) return bad(r, node, 0, "%s holds the control character 0x%02x", field, c);
  }
  return 0;
}

/* A path (string) joined with the catalogue's directory into out. */
static int path_value(reader *r, int node, const char *field, char out[PATH_MAX]) {
  int rc = text_value(r, node, field, "a non-empty path", PATH_MAX - 1);
  if (rc != 0) return rc;
  const char *p = r->doc->nodes[node].str, *dir = r->base_dir;
  int n;
  if (p[0] == '/' || dir == NULL || dir[0] == '\0') n = snprintf(out, PATH_MAX, "%s", p);
  else n = snprintf(out, PATH_MAX, "%s%s%s", dir, dir[strlen(dir) - 1] == '/' ? "" : "/", p);
  if (n < 0 || n >= PATH_MAX)
    return bad(r, node, 0, "%s: the path joined with %s is too long (%d bytes, at most %d)", field, dir, n,
               PATH_MAX - 1);
  return 0;
}

/* --- classes ---------------------------------------------------------------- */

/* The kind and usage weight of class c (both optional). */
static int class_kind(reader *r, int obj, ts_cat_class *c) {
  char g[64];
  int k = ts_json_member(r->doc, obj, "kind");
  c->kind = TS_CAT_STOCHASTIC;
  if (k >= 0) {
    const ts_json_node *n = &r->doc->nodes[k];
    if (n->type == TS_JSON_STRING && strcmp(n->str, kind_names[TS_CAT_STRUCTURED]) == 0) c->kind = TS_CAT_STRUCTURED;
    else if (n->type != TS_JSON_STRING || strcmp(n->str, kind_names[TS_CAT_STOCHASTIC]) != 0)
      return bad(r, k, 0, "kind must be \"stochastic\" or \"structured\", %s", got(r, k, g, sizeof(g)));
  }
  c->usage_weight = c->kind == TS_CAT_STRUCTURED ? TS_CAT_STRUCTURED_WEIGHT : TS_CAT_STOCHASTIC_WEIGHT;
  int w = ts_json_member(r->doc, obj, "usage_weight");
  if (w >= 0) {
    const ts_json_node *n = &r->doc->nodes[w];
    if (n->type != TS_JSON_NUMBER || n->num < 0 || n->num > TS_CAT_MAX_WEIGHT)
      return bad(r, w, 0, "usage_weight must be a number 0..%g, %s", TS_CAT_MAX_WEIGHT, got(r, w, g, sizeof(g)));
    c->usage_weight = n->num;
  }
  return 0;
}

/* Class number i (from 0) must not repeat an earlier class's id or name. */
static int class_unique(reader *r, int i, int id_node, int name_node) {
  const ts_cat_class *c = &r->cat->cls[i];
  for (int j = 0; j < i; j++) {
    const ts_cat_class *o = &r->cat->cls[j];
    if (o->id == c->id)
      return bad(r, id_node, 0, "id %d is already the id of class %d (\"%s\")", c->id, j + 1, o->name);
    if (strcmp(o->name, c->name) == 0)
      return bad(r, name_node, 0, "the name \"%s\" is already the name of class %d (id %d)", c->name, j + 1, o->id);
  }
  return 0;
}

/* How messages name class i at obj: by its name once that is a good one. */
static void class_label(reader *r, int obj, int i) {
  const ts_json_node *nodes = r->doc->nodes;
  int name = ts_json_member(r->doc, obj, "name");
  int good = name >= 0 && nodes[name].type == TS_JSON_STRING && nodes[name].slen > 0 &&
             nodes[name].slen < TS_CAT_NAME_LEN;
  for (size_t k = 0; good && k < nodes[name].slen; k++)
    good = (unsigned char)nodes[name].str[k] >= 0x20 && nodes[name].str[k] != 0x7F;
  if (good) snprintf(r->what, sizeof(r->what), "class %d (\"%s\")", i + 1, nodes[name].str);
  else snprintf(r->what, sizeof(r->what), "class %d", i + 1);
}

static int read_class(reader *r, int obj, int i) {
  static const char *const known[] = {"id", "name", "reference", "kind", "usage_weight", NULL};
  ts_cat_class *c = &r->cat->cls[i];
  const ts_json_node *nodes = r->doc->nodes;
  char g[64];
  int id, name, ref, rc;
  long v;
  snprintf(r->what, sizeof(r->what), "class %d", i + 1);
  if (nodes[obj].type != TS_JSON_OBJECT)
    return bad(r, obj, 0, "a class must be an object {\"id\": ..., \"name\": ..., \"reference\": ...}, %s",
               got(r, obj, g, sizeof(g)));
  class_label(r, obj, i);
  if ((rc = only_known_keys(r, obj, known)) != 0) return rc;
  if ((rc = required(r, obj, "id", "a whole number 0..65535, the class's value in the class map", &id)) != 0 ||
      (rc = whole_number(r, id, "id", 0, TS_CAT_MAX_ID, &v)) != 0)
    return rc;
  c->id = (int)v;
  if ((rc = required(r, obj, "name", "a non-empty string", &name)) != 0 ||
      (rc = text_value(r, name, "name", "a non-empty string", TS_CAT_NAME_LEN - 1)) != 0)
    return rc;
  memcpy(c->name, nodes[name].str, nodes[name].slen + 1);
  if ((rc = required(r, obj, "reference", "the path of its reference texture", &ref)) != 0 ||
      (rc = path_value(r, ref, "reference", c->reference)) != 0)
    return rc;
  ts_json_where(r->doc, nodes[ref].off, &c->line, &c->col);
  if ((rc = class_kind(r, obj, c)) != 0) return rc;
  return class_unique(r, i, id, name);
}

static int read_classes(reader *r, int list) {
  const ts_json_node *nodes = r->doc->nodes;
  char g[64];
  snprintf(r->what, sizeof(r->what), "classes");
  if (nodes[list].type != TS_JSON_ARRAY || nodes[list].count == 0)
    return bad(r, list, 0, "must be a list of 1..%d classes [{\"id\": ..., ...}, ...], %s", TS_CAT_MAX_CLASSES,
               nodes[list].type == TS_JSON_ARRAY ? "got an empty one" : got(r, list, g, sizeof(g)));
  if (nodes[list].count > TS_CAT_MAX_CLASSES)
    return bad(r, list, 0, "%d classes, more than the %d a catalogue may hold", nodes[list].count, TS_CAT_MAX_CLASSES);
  int i = 0;
  for (int m = nodes[list].first; m >= 0; m = nodes[m].next, i++) {
    int rc = read_class(r, m, i);
    if (rc != 0) return rc;
    r->cat->nclass = i + 1;
  }
  return 0;
}

/* --- lines -------------------------------------------------------------------- */

/* A colour key: a pixel value 0..65535 in plain decimal. */
static int colour_key(reader *r, int node, uint32_t *value) {
  const ts_json_node *n = &r->doc->nodes[node];
  uint32_t v = 0;
  int ok = n->klen > 0 && n->klen <= 5 && !(n->klen > 1 && n->key[0] == '0');
  for (size_t i = 0; ok && i < n->klen; i++) {
    ok = n->key[i] >= '0' && n->key[i] <= '9';
    v = v * 10 + (uint32_t)(n->key[i] - '0');
  }
  if (!ok || v > TS_CAT_MAX_ID)
    return bad(r, node, 1, "the key \"%.40s\" is not a pixel value of the line raster (0..65535 in decimal, "
               "no sign or leading zero)", n->key);
  *value = v;
  return 0;
}

/* A colour: [R, G, B] or one grey level, each 0..255. */
static int colour_value(reader *r, int node, uint8_t rgb[3]) {
  const ts_json_node *nodes = r->doc->nodes;
  char g[64];
  long v;
  if (nodes[node].type == TS_JSON_NUMBER) {
    int rc = whole_number(r, node, "a grey level", 0, 255, &v);
    if (rc != 0) return rc;
    rgb[0] = rgb[1] = rgb[2] = (uint8_t)v;
    return 0;
  }
  if (nodes[node].type != TS_JSON_ARRAY || nodes[node].count != 3)
    return bad(r, node, 0, "a colour is [R, G, B] (each 0..255) or one grey level 0..255, %s%s",
               got(r, node, g, sizeof(g)),
               nodes[node].type == TS_JSON_ARRAY && nodes[node].count == 4
                   ? " (no alpha: lines are drawn opaque)"
                   : nodes[node].type == TS_JSON_ARRAY ? " of the wrong length" : "");
  int k = 0;
  for (int m = nodes[node].first; m >= 0; m = nodes[m].next, k++) {
    static const char *const part[] = {"red", "green", "blue"};
    int rc = whole_number(r, m, part[k], 0, 255, &v);
    if (rc != 0) return rc;
    rgb[k] = (uint8_t)v;
  }
  return 0;
}

static int read_colours(reader *r, int obj) {
  const ts_json_node *nodes = r->doc->nodes;
  ts_catalogue *cat = r->cat;
  char g[64];
  if (nodes[obj].type != TS_JSON_OBJECT || nodes[obj].count == 0)
    return bad(r, obj, 0, "colours must map pixel values to colours, e.g. {\"255\": [90, 90, 90]}, %s",
               nodes[obj].type == TS_JSON_OBJECT ? "got an empty object (no line would be drawn)"
                                                 : got(r, obj, g, sizeof(g)));
  if (nodes[obj].count > TS_CAT_MAX_COLOURS)
    return bad(r, obj, 0, "%d colours, more than the %d a catalogue may hold", nodes[obj].count, TS_CAT_MAX_COLOURS);
  for (int m = nodes[obj].first; m >= 0; m = nodes[m].next) {
    ts_cat_colour *c = &cat->colour[cat->ncolours];
    int rc;
    if ((rc = colour_key(r, m, &c->value)) != 0) return rc;
    snprintf(r->what, sizeof(r->what), "lines: colours \"%u\"", c->value);
    if ((rc = colour_value(r, m, c->rgb)) != 0) return rc;
    snprintf(r->what, sizeof(r->what), "lines");
    cat->ncolours++;
  }
  return 0;
}

/* A vector layer's rules (gis.h's JSON form, beside "vector" and
 * "colours"), each value given a colour: a line without one would not be
 * drawn. The engine reads the rules again from the catalogue itself. */
static int read_vector_rules(reader *r, int obj) {
  static const char *const mine[] = {"vector", "colours", NULL};
  ts_gis_line_rules *rules = malloc(sizeof(*rules));
  if (rules == NULL) return ts_error(r->err, TS_ENOMEM, "out of memory");
  int rc = ts_gis_line_rules_read(r->doc, obj, mine, rules, r->err);
  for (int k = 0; rc == 0 && k < rules->nrule; k++) {
    int c = 0;
    while (c < r->cat->ncolours && r->cat->colour[c].value != rules->rule[k].value) c++;
    if (c == r->cat->ncolours)
      rc = bad(r, obj, 0, "rule %d (\"%s\") draws value %u, which \"colours\" gives no colour; add \"%u\": [R, G, B]",
               k + 1, rules->rule[k].match, rules->rule[k].value, rules->rule[k].value);
  }
  free(rules);
  return rc;
}

static int read_lines(reader *r, int obj) {
  static const char *const raster_keys[] = {"raster", "colours", NULL};
  static const char *const vector_keys[] = {"vector", "colours", "layer", "field", "width_field", "rules", NULL};
  const ts_json_node *nodes = r->doc->nodes;
  char g[64];
  int path, colours, rc, vector = ts_json_member(r->doc, obj, "vector") >= 0;
  snprintf(r->what, sizeof(r->what), "lines");
  if (nodes[obj].type != TS_JSON_OBJECT)
    return bad(r, obj, 0, "must be an object {\"raster\": ..., \"colours\": {...}} or {\"vector\": ..., \"rules\": "
               "[...], \"colours\": {...}}, %s", got(r, obj, g, sizeof(g)));
  if (vector && ts_json_member(r->doc, obj, "raster") >= 0)
    return bad(r, obj, 0, "give either \"raster\" (a line raster) or \"vector\" (a vector layer), not both");
  if ((rc = only_known_keys(r, obj, vector ? vector_keys : raster_keys)) != 0) return rc;
  const char *key = vector ? "vector" : "raster";
  if ((rc = required(r, obj, key, vector ? "the path of the vector layer" : "the path of the line raster", &path)) != 0 ||
      (rc = path_value(r, path, key, r->cat->line_raster)) != 0)
    return rc;
  ts_json_where(r->doc, nodes[path].off, &r->cat->raster_line, &r->cat->raster_col);
  if ((rc = required(r, obj, "colours", "pixel values to colours, e.g. {\"255\": [90, 90, 90]}", &colours)) != 0 ||
      (rc = read_colours(r, colours)) != 0)
    return rc;
  if (vector && (rc = read_vector_rules(r, obj)) != 0) return rc;
  r->cat->has_lines = 1;
  r->cat->line_vector = vector;
  return 0;
}

/* --- the whole ----------------------------------------------------------------- */

static int read_catalogue(reader *r) {
  static const char *const known[] = {"classes", "lines", NULL};
  const ts_json_node *root = &r->doc->nodes[0];
  char g[64];
  int classes, rc;
  snprintf(r->what, sizeof(r->what), "catalogue");
  if (root->type != TS_JSON_OBJECT)
    return bad(r, 0, 0, "must be an object {\"classes\": [...], \"lines\": {...}}, %s", got(r, 0, g, sizeof(g)));
  if ((rc = only_known_keys(r, 0, known)) != 0) return rc;
  if ((rc = required(r, 0, "classes", "the list of classes", &classes)) != 0 || (rc = read_classes(r, classes)) != 0)
    return rc;
  int lines = ts_json_member(r->doc, 0, "lines");
  return lines >= 0 ? read_lines(r, lines) : 0;
}

int ts_catalogue_parse(const char *text, size_t len, const char *name, const char *base_dir, ts_catalogue *out,
                       char *err) {
  memset(out, 0, sizeof(*out));
  ts_json_doc doc;
  int rc = ts_json_parse(&doc, name, text, len, TS_CAT_MAX_NODES, err);
  if (rc != 0) return rc;
  reader r = {&doc, base_dir, out, err, ""};
  rc = read_catalogue(&r);
  ts_json_free(&doc);
  if (rc != 0) memset(out, 0, sizeof(*out));
  return rc;
}

/* --- files ------------------------------------------------------------------------ */

/* path, named at line:col of the catalogue, is an existing regular file. */
static int check_file(const char *cat_path, int line, int col, const char *what, const char *path, char *err) {
  struct stat st;
  if (stat(path, &st) != 0)
    return ts_error(err, TS_ENOENT, "%s:%d:%d: %s: %s: %s", cat_path, line, col, what, path, strerror(errno));
  if (!S_ISREG(st.st_mode))
    return ts_error(err, TS_ENOENT, "%s:%d:%d: %s: %s is not a regular file", cat_path, line, col, what, path);
  return 0;
}

static int check_files(const char *path, const ts_catalogue *cat, char *err) {
  char what[96];
  for (int i = 0; i < cat->nclass; i++) {
    const ts_cat_class *c = &cat->cls[i];
    snprintf(what, sizeof(what), "class %d (\"%s\"): reference", i + 1, c->name);
    int rc = check_file(path, c->line, c->col, what, c->reference, err);
    if (rc != 0) return rc;
  }
  return cat->has_lines ? check_file(path, cat->raster_line, cat->raster_col,
                                    cat->line_vector ? "lines: vector" : "lines: raster", cat->line_raster, err)
                        : 0;
}

int ts_catalogue_load(const char *path, ts_catalogue *out, char *err) {
  uint8_t *text;
  size_t len;
  memset(out, 0, sizeof(*out));
  int rc = ts_file_read(path, TS_CAT_MAX_BYTES, &text, &len, err);
  if (rc == TS_ETOOBIG)
    return ts_error(err, rc, "%s is %zu bytes: a catalogue is at most %d (1 MiB); is it the right file?", path, len,
                    TS_CAT_MAX_BYTES);
  if (rc != 0) return rc;
  char dir[PATH_MAX];
  const char *slash = strrchr(path, '/');
  size_t n = slash == NULL ? 0 : slash == path ? 1 : (size_t)(slash - path);
  if (n >= sizeof(dir)) {
    free(text);
    return ts_error(err, TS_EINVAL, "%s: the path is too long", path);
  }
  memcpy(dir, path, n);
  dir[n] = '\0';
  rc = ts_catalogue_parse((const char *)text, len, path, dir, out, err);
  free(text);
  if (rc == 0 && (rc = check_files(path, out, err)) != 0) memset(out, 0, sizeof(*out));
  return rc;
}
