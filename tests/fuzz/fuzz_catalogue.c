/* fuzz_catalogue.c - libFuzzer target for the aerial catalogue parser
 * (server/cli/catalogue.c) and the JSON reader under it (common/json.c).
 * The input is the catalogue's text, not NUL-terminated. The DOM of any
 * text the reader accepts must be well formed (links, counts, offsets
 * within the text, decoded strings terminated); a catalogue the parser
 * accepts must hold what catalogue.h promises; a refusal must say where.
 * Any crash, sanitizer report or broken promise is a bug. Build and run:
 * make fuzz. */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "catalogue.h"
#include "error.h"
#include "json.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

/* The message of a refusal: terminated, not empty, and placed in the text
 * ("fuzz.json:LINE:COL: ...") unless memory ran out. */
static void check_message(int rc, const char *err) {
  if (memchr(err, '\0', TS_ERR_LEN) == NULL || err[0] == '\0') abort();
  if (rc != TS_ENOMEM && strncmp(err, "fuzz.json:", 10) != 0) abort();
}

/* Every node's members are linked, counted and inside their parent. */
static void check_dom(const ts_json_doc *d) {
  int linked = 1; /* the root */
  for (int i = 0; i < d->nnodes; i++) {
    const ts_json_node *n = &d->nodes[i];
    if (n->off > n->end || n->end > d->len) abort();
    if (n->type == TS_JSON_STRING && (n->str == NULL || n->str[n->slen] != '\0')) abort();
    if (n->type != TS_JSON_ARRAY && n->type != TS_JSON_OBJECT) {
      if (n->count != 0 || n->first != -1) abort();
      continue;
    }
    int count = 0;
    for (int m = n->first; m >= 0; m = d->nodes[m].next, count++) {
      const ts_json_node *c = &d->nodes[m];
      if (m <= i || m >= d->nnodes || c->off <= n->off || c->end >= n->end) abort();
      if ((n->type == TS_JSON_OBJECT) != (c->key != NULL)) abort();
      if (c->key != NULL && (c->key[c->klen] != '\0' || c->key_off <= n->off || c->key_off >= c->off)) abort();
    }
    if (count != n->count) abort();
    linked += count;
  }
  if (linked != d->nnodes) abort(); /* no node left out, none linked twice */
}

static void check_catalogue(const ts_catalogue *c) {
  if (c->nclass < 1 || c->nclass > TS_CAT_MAX_CLASSES) abort();
  for (int i = 0; i < c->nclass; i++) {
    const ts_cat_class *k = &c->cls[i];
    size_t n = strnlen(k->name, TS_CAT_NAME_LEN);
    if (n == 0 || n == TS_CAT_NAME_LEN || strnlen(k->reference, PATH_MAX) == 0) abort();
    if (k->id < 0 || k->id > TS_CAT_MAX_ID || k->line < 1 || k->col < 1) abort();
    if (!(k->usage_weight >= 0 && k->usage_weight <= TS_CAT_MAX_WEIGHT)) abort();
    for (int j = 0; j < i; j++)
      if (c->cls[j].id == k->id || strcmp(c->cls[j].name, k->name) == 0) abort();
  }
  if (!c->has_lines) {
    if (c->ncolours != 0) abort();
    return;
  }
  if (c->ncolours < 1 || c->ncolours > TS_CAT_MAX_COLOURS || c->line_raster[0] == '\0') abort();
  for (int i = 0; i < c->ncolours; i++) {
    if (c->colour[i].value > TS_CAT_MAX_ID) abort();
    for (int j = 0; j < i; j++)
      if (c->colour[j].value == c->colour[i].value) abort();
  }
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  char err[TS_ERR_LEN];
  /* An exact-size copy, so reading one byte past the input is caught. */
  char *text = malloc(size ? size : 1);
  if (text == NULL) return 0;
  if (size) memcpy(text, data, size);
  ts_json_doc doc;
  int rc = ts_json_parse(&doc, "fuzz.json", text, size, 4096, err);
  if (rc != 0) {
    check_message(rc, err);
  } else {
    check_dom(&doc);
    ts_json_free(&doc);
  }
  ts_catalogue *cat = malloc(sizeof(*cat));
  if (cat != NULL) {
    rc = ts_catalogue_parse(text, size, "fuzz.json", "/cat", cat, err);
    if (rc != 0) check_message(rc, err);
    else check_catalogue(cat);
    free(cat);
  }
  free(text);
  return 0;
}
