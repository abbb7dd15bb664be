/* json.c - see json.h.
 *
 * One pass over the text with an explicit stack of open containers: a
 * value is read (a scalar whole, a container only opened), linked to its
 * parent, and then the separators are read until the next value is due.
 * Strings are decoded straight into the pool, which is allocated once at
 * len + 1 bytes: a string's decoded bytes and its NUL never take more room
 * than its quoted text (an escape shrinks, UTF-8 is copied as is), so the
 * pool never moves and the string pointers stay valid. */
#include "json.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"

/* Longest number text taken; longer ones say so rather than lose digits. */
#define TS_JSON_MAX_NUMBER 512

typedef struct {
  ts_json_doc *doc;
  const unsigned char *s;
  size_t len, pos;
  size_t pool_used;
  int cap, max_nodes;
  char *err;
} parser;

/* An open container and its last member so far (-1: none yet). */
typedef struct {
  int node, last;
} level;

/* The key read for the next value of an object. */
typedef struct {
  const char *key;
  size_t klen, off;
} pending_key;

/* --- positions and messages --------------------------------------------- */

void ts_json_where(const ts_json_doc *doc, size_t off, int *line, int *col) {
  const unsigned char *s = (const unsigned char *)doc->text;
  if (off > doc->len) off = doc->len;
  int l = 1, c = 1;
  for (size_t i = 0; i < off; i++) {
    if (s[i] == '\n') {
      l++;
      c = 1;
    } else if ((s[i] & 0xC0) != 0x80) { /* not a UTF-8 continuation byte */
      c++;
    }
  }
  *line = l;
  *col = c;
}

/* "NAME:LINE:COL: message" for byte off; returns code. */
__attribute__((format(printf, 4, 5))) static int fail(parser *p, size_t off, int code,
                                                       const char *fmt, ...) {
  char msg[TS_ERR_LEN];
  va_list ap;
  va_start(ap, fmt);
  vsnprintf(msg, sizeof(msg), fmt, ap);
  va_end(ap);
  int line, col;
  ts_json_where(p->doc, off, &line, &col);
  return ts_error(p->err, code, "%s:%d:%d: %s", p->doc->name, line, col, msg);
}

/* What is at byte off, for "got ..." in messages. */
static const char *found(const parser *p, size_t off, char *buf, size_t cap) {
  if (off >= p->len) return "the end of the text";
  unsigned char c = p->s[off];
  if (c > 0x20 && c < 0x7F) snprintf(buf, cap, "'%c'", c);
  else snprintf(buf, cap, "byte 0x%02x", c);
  return buf;
}

/* Where a container was opened, for messages about closing it. */
static const char *opened_at(const parser *p, int node, char *buf, size_t cap) {
  int line, col;
  ts_json_where(p->doc, p->doc->nodes[node].off, &line, &col);
  snprintf(buf, cap, "the %s opened at %d:%d", p->doc->nodes[node].type == TS_JSON_OBJECT ? "object" : "array",
           line, col);
  return buf;
}

const char *ts_json_type_name(ts_json_type type) {
  switch (type) {
  case TS_JSON_NULL:
    return "null";
  case TS_JSON_FALSE:
  case TS_JSON_TRUE:
    return "a boolean";
  case TS_JSON_NUMBER:
    return "a number";
  case TS_JSON_STRING:
    return "a string";
  case TS_JSON_ARRAY:
    return "an array";
  case TS_JSON_OBJECT:
    return "an object";
  }
  return "a value";
}

void ts_json_quote(const ts_json_doc *doc, int node, char *buf, size_t cap) {
  const ts_json_node *n = &doc->nodes[node];
  if (n->type == TS_JSON_ARRAY || n->type == TS_JSON_OBJECT) {
    snprintf(buf, cap, "%s", ts_json_type_name(n->type));
    return;
  }
  size_t len = n->end - n->off, room = cap > 4 ? cap - 4 : 0; /* "..." and NUL */
  if (len < cap) {
    memcpy(buf, doc->text + n->off, len);
    buf[len] = '\0';
    return;
  }
  /* Cut on a character boundary, so the message stays valid UTF-8. */
  while (room > 0 && ((unsigned char)doc->text[n->off + room] & 0xC0) == 0x80) room--;
  memcpy(buf, doc->text + n->off, room);
  snprintf(buf + room, cap - room, "...");
}

/* --- nodes ---------------------------------------------------------------- */

static int new_node(parser *p, ts_json_type type, int *out) {
  ts_json_doc *d = p->doc;
  if (d->nnodes == p->max_nodes)
    return fail(p, p->pos, TS_ELIMIT, "more than %d values: too many for this reader", p->max_nodes);
  if (d->nnodes == p->cap) {
    int cap = p->cap ? p->cap * 2 : 64;
    if (cap > p->max_nodes) cap = p->max_nodes;
    ts_json_node *n = realloc(d->nodes, (size_t)cap * sizeof(*n));
    if (n == NULL) return ts_error(p->err, TS_ENOMEM, "%s: out of memory for %d JSON values", d->name, cap);
    d->nodes = n;
    p->cap = cap;
  }
  ts_json_node *n = &d->nodes[d->nnodes];
  memset(n, 0, sizeof(*n));
  n->type = type;
  n->off = n->end = p->pos;
  n->first = n->next = -1;
  *out = d->nnodes++;
  return 0;
}

/* Links node as the next member of the innermost open container. */
static void attach(parser *p, level *top, int node, pending_key *key) {
  ts_json_node *nodes = p->doc->nodes;
  if (top == NULL) return;
  if (top->last < 0) nodes[top->node].first = node;
  else nodes[top->last].next = node;
  top->last = node;
  nodes[top->node].count++;
  if (key->key != NULL) {
    nodes[node].key = key->key;
    nodes[node].klen = key->klen;
    nodes[node].key_off = key->off;
    key->key = NULL;
  }
}

/* --- lexing --------------------------------------------------------------- */

static void skip_ws(parser *p) {
  while (p->pos < p->len) {
    unsigned char c = p->s[p->pos];
    if (c != ' ' && c != '\t' && c != '\n' && c != '\r') return;
    p->pos++;
  }
}

static int peek(const parser *p) { return p->pos < p->len ? p->s[p->pos] : -1; }

/* Bytes of the valid UTF-8 character at s (n bytes left), 0 if invalid:
 * no stray continuation bytes, no overlong forms (C0, C1, E0 80..9F,
 * F0 80..8F), no surrogates (ED A0..BF), nothing above U+10FFFF. */
static size_t utf8_len(const unsigned char *s, size_t n) {
  unsigned char c = s[0];
  size_t need;
  unsigned char lo = 0x80, hi = 0xBF;
  if (c < 0x80) return 1;
  if (c < 0xC2) return 0;
  if (c < 0xE0) {
    need = 2;
  } else if (c < 0xF0) {
    need = 3;
    if (c == 0xE0) lo = 0xA0;
    if (c == 0xED) hi = 0x9F;
  } else if (c < 0xF5) {
    need = 4;
    if (c == 0xF0) lo = 0x90;
    if (c == 0xF4) hi = 0x8F;
  } else {
    return 0;
  }
  if (n < need || s[1] < lo || s[1] > hi) return 0;
  for (size_t i = 2; i < need; i++)
    if ((s[i] & 0xC0) != 0x80) return 0;
  return need;
}

static size_t utf8_put(char *out, uint32_t cp) {
  if (cp < 0x80) {
    out[0] = (char)cp;
    return 1;
  }
  if (cp < 0x800) {
    out[0] = (char)(0xC0 | (cp >> 6));
    out[1] = (char)(0x80 | (cp & 0x3F));
    return 2;
  }
  if (cp < 0x10000) {
    out[0] = (char)(0xE0 | (cp >> 12));
    out[1] = (char)(0x80 | ((cp >> 6) & 0x3F));
    out[2] = (char)(0x80 | (cp & 0x3F));
    return 3;
  }
  out[0] = (char)(0xF0 | (cp >> 18));
  out[1] = (char)(0x80 | ((cp >> 12) & 0x3F));
  out[2] = (char)(0x80 | ((cp >> 6) & 0x3F));
  out[3] = (char)(0x80 | (cp & 0x3F));
  return 4;
}

/* The four hex digits of a \u escape starting at the backslash at, or -1. */
static long hex4(const parser *p, size_t at) {
  if (at + 6 > p->len || p->s[at] != '\\' || p->s[at + 1] != 'u') return -1;
  long v = 0;
  for (size_t i = at + 2; i < at + 6; i++) {
    unsigned char c = p->s[i];
    int d = c >= '0' && c <= '9' ? c - '0' : c >= 'a' && c <= 'f' ? c - 'a' + 10 : c >= 'A' && c <= 'F' ? c - 'A' + 10 : -1;
    if (d < 0) return -1;
    v = v * 16 + d;
  }
  return v;
}

/* The \u escape at p->pos (a backslash) as a code point, joining a
 * surrogate pair; advances past it. */
static int read_u_escape(parser *p, uint32_t *cp) {
  size_t at = p->pos;
  long hi = hex4(p, at);
  if (hi < 0) return fail(p, at, TS_EFORMAT, "\\u must be followed by 4 hex digits");
  p->pos += 6;
  if (hi >= 0xDC00 && hi <= 0xDFFF)
    return fail(p, at, TS_EFORMAT, "lone low surrogate \\u%04lX (it must follow a high surrogate \\uD800..\\uDBFF)",
                hi);
  if (hi < 0xD800 || hi > 0xDBFF) {
    *cp = (uint32_t)hi;
    return 0;
  }
  long lo = hex4(p, p->pos);
  if (lo < 0xDC00 || lo > 0xDFFF)
    return fail(p, at, TS_EFORMAT, "lone high surrogate \\u%04lX (a low surrogate \\uDC00..\\uDFFF must follow)", hi);
  p->pos += 6;
  *cp = 0x10000 + (((uint32_t)hi - 0xD800) << 10) + ((uint32_t)lo - 0xDC00);
  return 0;
}

/* The escape at p->pos (a backslash), decoded to out; advances past it. */
static int read_escape(parser *p, char *out, size_t *n) {
  static const char from[] = "\"\\/bfnrt", to[] = "\"\\/\b\f\n\r\t";
  if (p->pos + 1 >= p->len) return fail(p, p->pos, TS_EFORMAT, "unterminated string: the text ends in an escape");
  unsigned char e = p->s[p->pos + 1];
  if (e == 'u') {
    uint32_t cp = 0;
    int rc = read_u_escape(p, &cp);
    if (rc != 0) return rc;
    *n = utf8_put(out, cp);
    return 0;
  }
  const char *k = e != '\0' ? strchr(from, e) : NULL;
  if (k == NULL) {
    char what[16];
    return fail(p, p->pos, TS_EFORMAT, "invalid escape: a backslash followed by %s (valid: \\\" \\\\ \\/ \\b \\f \\n \\r \\t \\uHHHH)",
                found(p, p->pos + 1, what, sizeof(what)));
  }
  out[0] = to[k - from];
  *n = 1;
  p->pos += 2;
  return 0;
}

/* The string whose opening quote is at p->pos, decoded into the pool;
 * advances past the closing quote. */
static int read_string(parser *p, const char **str, size_t *slen) {
  size_t start = p->pos++;
  char *out = p->doc->pool + p->pool_used;
  size_t n = 0;
  for (;;) {
    if (p->pos >= p->len) return fail(p, start, TS_EFORMAT, "unterminated string: no closing '\"' for the '\"' here");
    unsigned char c = p->s[p->pos];
    if (c == '"') break;
    size_t k = 0;
    if (c == '\\') {
      int rc = read_escape(p, out + n, &k);
      if (rc != 0) return rc;
      n += k;
      continue;
    }
    if (c == '\n' || c == '\r')
      return fail(p, start, TS_EFORMAT, "unterminated string: a line break before its closing '\"' (write it as \\n)");
    if (c < 0x20)
      return fail(p, p->pos, TS_EFORMAT, "control character 0x%02x in a string: write it as \\u%04X", c, c);
    k = utf8_len(p->s + p->pos, p->len - p->pos);
    if (k == 0) return fail(p, p->pos, TS_EFORMAT, "invalid UTF-8 in a string (byte 0x%02x)", c);
    memcpy(out + n, p->s + p->pos, k);
    n += k;
    p->pos += k;
  }
  p->pos++;
  out[n] = '\0';
  p->pool_used += n + 1;
  *str = out;
  *slen = n;
  return 0;
}

static int is_digit(int c) { return c >= '0' && c <= '9'; }

static void skip_digits(parser *p) {
  while (is_digit(peek(p))) p->pos++;
}

/* The number at p->pos: -?(0|[1-9][0-9]*)(.[0-9]+)?([eE][+-]?[0-9]+)? */
static int read_number(parser *p, double *out) {
  size_t start = p->pos;
  char what[16];
  if (peek(p) == '-') p->pos++;
  if (!is_digit(peek(p)))
    return fail(p, p->pos, TS_EFORMAT, "expected a digit after '-', got %s", found(p, p->pos, what, sizeof(what)));
  if (peek(p) == '0') {
    p->pos++;
    if (is_digit(peek(p))) return fail(p, start, TS_EFORMAT, "a number may not have leading zeros");
  } else {
    skip_digits(p);
  }
  if (peek(p) == '.') {
    p->pos++;
    if (!is_digit(peek(p)))
      return fail(p, p->pos, TS_EFORMAT, "expected a digit after the decimal point, got %s",
                  found(p, p->pos, what, sizeof(what)));
    skip_digits(p);
  }
  if (peek(p) == 'e' || peek(p) == 'E') {
    p->pos++;
    if (peek(p) == '+' || peek(p) == '-') p->pos++;
    if (!is_digit(peek(p)))
      return fail(p, p->pos, TS_EFORMAT, "expected a digit in the exponent, got %s",
                  found(p, p->pos, what, sizeof(what)));
    skip_digits(p);
  }
  size_t n = p->pos - start;
  if (n > TS_JSON_MAX_NUMBER)
    return fail(p, start, TS_EFORMAT, "a number of %zu characters (at most %d are read)", n, TS_JSON_MAX_NUMBER);
  char buf[TS_JSON_MAX_NUMBER + 1];
  memcpy(buf, p->s + start, n);
  buf[n] = '\0';
  /* The grammar above is a subset of strtod's in the C locale, which
   * texsyn never changes; only the range is left to check. */
  *out = strtod(buf, NULL);
  if (isinf(*out)) return fail(p, start, TS_EFORMAT, "the number %s is too large (beyond a double's range)", buf);
  return 0;
}

/* A bare word (for true/false/null, or naming what is wrong). */
static size_t word_len(const parser *p) {
  size_t n = 0;
  while (p->pos + n < p->len) {
    unsigned char c = p->s[p->pos + n];
    if (!((c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || is_digit(c) || c == '_')) break;
    n++;
  }
  return n;
}

static int bad_value(parser *p) {
  char what[48];
  int c = peek(p);
  size_t n = word_len(p);
  if (c == '\'') return fail(p, p->pos, TS_EFORMAT, "strings take double quotes (\"), not single ones");
  if (c == '/') return fail(p, p->pos, TS_EFORMAT, "comments are not allowed in JSON");
  if (n > 0) {
    snprintf(what, sizeof(what), "'%.*s'", n > 24 ? 24 : (int)n, (const char *)p->s + p->pos);
    return fail(p, p->pos, TS_EFORMAT,
                "expected a value (an object, array, string, number, true, false or null), got %s%s", what,
                n > 24 ? "..." : "");
  }
  return fail(p, p->pos, TS_EFORMAT, "expected a value (an object, array, string, number, true, false or null), got %s",
              found(p, p->pos, what, sizeof(what)));
}

/* The value at p->pos as a new node: a scalar whole, a container opened. */
static int read_value(parser *p, int *node) {
  static const struct {
    const char *word;
    ts_json_type type;
  } words[] = {{"true", TS_JSON_TRUE}, {"false", TS_JSON_FALSE}, {"null", TS_JSON_NULL}};
  int c = peek(p), rc;
  if (c == '{' || c == '[') {
    rc = new_node(p, c == '{' ? TS_JSON_OBJECT : TS_JSON_ARRAY, node);
    if (rc == 0) p->pos++;
    return rc;
  }
  if (c == '"') {
    if ((rc = new_node(p, TS_JSON_STRING, node)) != 0) return rc;
    const char *s;
    size_t n;
    if ((rc = read_string(p, &s, &n)) != 0) return rc;
    p->doc->nodes[*node].str = s;
    p->doc->nodes[*node].slen = n;
  } else if (c == '-' || is_digit(c)) {
    if ((rc = new_node(p, TS_JSON_NUMBER, node)) != 0) return rc;
    double v = 0;
    if ((rc = read_number(p, &v)) != 0) return rc;
    p->doc->nodes[*node].num = v;
  } else {
    size_t n = word_len(p), i;
    for (i = 0; i < sizeof(words) / sizeof(words[0]); i++)
      if (n == strlen(words[i].word) && memcmp(p->s + p->pos, words[i].word, n) == 0) break;
    if (i == sizeof(words) / sizeof(words[0])) return bad_value(p);
    if ((rc = new_node(p, words[i].type, node)) != 0) return rc;
    p->pos += n;
  }
  p->doc->nodes[*node].end = p->pos;
  return 0;
}

/* The key of the next member and its ':' (white space skipped). */
static int read_key(parser *p, int obj, pending_key *key) {
  char what[16], where[64];
  skip_ws(p);
  if (peek(p) != '"') {
    if (peek(p) == '\'') return fail(p, p->pos, TS_EFORMAT, "keys take double quotes (\"), not single ones");
    if (peek(p) < 0)
      return fail(p, p->pos, TS_EFORMAT, "the text ends inside %s", opened_at(p, obj, where, sizeof(where)));
    return fail(p, p->pos, TS_EFORMAT, "expected a key in double quotes, got %s", found(p, p->pos, what, sizeof(what)));
  }
  key->off = p->pos;
  int rc = read_string(p, &key->key, &key->klen);
  if (rc != 0) return rc;
  skip_ws(p);
  if (peek(p) != ':')
    return fail(p, p->pos, TS_EFORMAT, "expected ':' after the key \"%.40s\", got %s", key->key,
                found(p, p->pos, what, sizeof(what)));
  p->pos++;
  return 0;
}

/* --- unique keys ------------------------------------------------------------ */

typedef struct {
  const char *key;
  size_t klen, off;
} key_ref;

static int same_key(const key_ref *x, const key_ref *y) {
  return x->klen == y->klen && memcmp(x->key, y->key, x->klen) == 0;
}

static int by_key_then_place(const void *a, const void *b) {
  const key_ref *x = a, *y = b;
  size_t n = x->klen < y->klen ? x->klen : y->klen;
  int c = memcmp(x->key, y->key, n);
  if (c != 0) return c;
  if (x->klen != y->klen) return x->klen < y->klen ? -1 : 1;
  return x->off < y->off ? -1 : x->off > y->off;
}

/* The closed object obj has unique keys; else the earliest repeat is
 * named, with where the key came first. Sorting makes this n log n, so a
 * huge object cannot make it quadratic. */
static int check_unique(parser *p, int obj) {
  const ts_json_node *nodes = p->doc->nodes;
  int n = nodes[obj].count;
  if (n < 2) return 0;
  key_ref *k = malloc((size_t)n * sizeof(*k));
  if (k == NULL) return ts_error(p->err, TS_ENOMEM, "%s: out of memory checking %d keys", p->doc->name, n);
  int i = 0;
  for (int m = nodes[obj].first; m >= 0; m = nodes[m].next, i++)
    k[i] = (key_ref){nodes[m].key, nodes[m].klen, nodes[m].key_off};
  qsort(k, (size_t)n, sizeof(*k), by_key_then_place);
  int dup = -1, first = -1; /* the repeat with the smallest offset, its key's first place */
  for (i = 1; i < n; i++) {
    if (!same_key(&k[i], &k[i - 1])) continue;
    if (dup < 0 || k[i].off < k[dup].off) {
      dup = i;
      for (first = i - 1; first > 0 && same_key(&k[first - 1], &k[i]); first--) continue;
    }
  }
  int rc = 0;
  if (dup >= 0) {
    int line, col;
    ts_json_where(p->doc, k[first].off, &line, &col);
    rc = fail(p, k[dup].off, TS_EFORMAT, "duplicate key \"%.40s\" (first given at %d:%d)", k[dup].key, line, col);
  }
  free(k);
  return rc;
}

/* --- the parser --------------------------------------------------------------- */

/* Closes the innermost container at p->pos (its closing bracket). */
static int close_level(parser *p, level *stack, int *depth) {
  int node = stack[--*depth].node;
  p->pos++;
  p->doc->nodes[node].end = p->pos;
  return p->doc->nodes[node].type == TS_JSON_OBJECT ? check_unique(p, node) : 0;
}

/* After a value: reads closing brackets and at most one ',' (and the next
 * key in an object). *done is set when the root value is complete. */
static int after_value(parser *p, level *stack, int *depth, pending_key *key, int *done) {
  char what[16], where[64];
  for (;;) {
    skip_ws(p);
    if (*depth == 0) {
      if (p->pos < p->len)
        return fail(p, p->pos, TS_EFORMAT, "unexpected %s after the end of the JSON value",
                    found(p, p->pos, what, sizeof(what)));
      *done = 1;
      return 0;
    }
    int node = stack[*depth - 1].node;
    int is_obj = p->doc->nodes[node].type == TS_JSON_OBJECT;
    int close = is_obj ? '}' : ']', c = peek(p);
    if (c == close) {
      int rc = close_level(p, stack, depth);
      if (rc != 0) return rc;
      continue;
    }
    if (c == ',') {
      size_t comma = p->pos++;
      skip_ws(p);
      if (peek(p) == close) return fail(p, comma, TS_EFORMAT, "a trailing comma before '%c' is not allowed", close);
      return is_obj ? read_key(p, node, key) : 0;
    }
    if (c < 0) return fail(p, p->pos, TS_EFORMAT, "the text ends inside %s", opened_at(p, node, where, sizeof(where)));
    return fail(p, p->pos, TS_EFORMAT, "expected ',' or '%c' after a member of %s, got %s", close,
                opened_at(p, node, where, sizeof(where)), found(p, p->pos, what, sizeof(what)));
  }
}

static int parse_text(parser *p) {
  level stack[TS_JSON_MAX_DEPTH];
  int depth = 0, done = 0, rc;
  pending_key key = {NULL, 0, 0};
  if (p->len >= 3 && memcmp(p->s, "\xEF\xBB\xBF", 3) == 0) p->pos = 3;
  while (!done) {
    skip_ws(p);
    if (peek(p) < 0) { /* a value is due, the text is over */
      char where[64];
      if (depth == 0) return fail(p, p->pos, TS_EFORMAT, "the text is empty: expected a JSON value");
      return fail(p, p->pos, TS_EFORMAT, "the text ends inside %s",
                  opened_at(p, stack[depth - 1].node, where, sizeof(where)));
    }
    int node = 0;
    if ((rc = read_value(p, &node)) != 0) return rc;
    attach(p, depth > 0 ? &stack[depth - 1] : NULL, node, &key);
    ts_json_type t = p->doc->nodes[node].type;
    if (t == TS_JSON_OBJECT || t == TS_JSON_ARRAY) {
      if (depth == TS_JSON_MAX_DEPTH)
        return fail(p, p->doc->nodes[node].off, TS_ELIMIT, "containers nested more than %d deep", TS_JSON_MAX_DEPTH);
      stack[depth++] = (level){node, -1};
      skip_ws(p);
      int close = t == TS_JSON_OBJECT ? '}' : ']';
      if (peek(p) != close) {
        if (t == TS_JSON_OBJECT && (rc = read_key(p, node, &key)) != 0) return rc;
        continue; /* the first member's value is next */
      }
      if ((rc = close_level(p, stack, &depth)) != 0) return rc;
    }
    if ((rc = after_value(p, stack, &depth, &key, &done)) != 0) return rc;
  }
  return 0;
}

int ts_json_parse(ts_json_doc *doc, const char *name, const char *text, size_t len, int max_nodes, char *err) {
  memset(doc, 0, sizeof(*doc));
  doc->name = name;
  doc->text = text;
  doc->len = len;
  if (max_nodes < 1) return ts_error(err, TS_EINVAL, "%s: a JSON reader needs room for at least one value", name);
  doc->pool = malloc(len + 1);
  if (doc->pool == NULL) return ts_error(err, TS_ENOMEM, "%s: out of memory for %zu bytes of JSON", name, len);
  parser p = {doc, (const unsigned char *)text, len, 0, 0, 0, max_nodes, err};
  int rc = parse_text(&p);
  if (rc != 0) ts_json_free(doc);
  return rc;
}

void ts_json_free(ts_json_doc *doc) {
  free(doc->nodes);
  free(doc->pool);
  doc->nodes = NULL;
  doc->pool = NULL;
  doc->nnodes = 0;
}

int ts_json_member(const ts_json_doc *doc, int obj, const char *key) {
  size_t n = strlen(key);
  for (int m = doc->nodes[obj].first; m >= 0; m = doc->nodes[m].next)
    if (doc->nodes[m].klen == n && memcmp(doc->nodes[m].key, key, n) == 0) return m;
  return -1;
}

int ts_json_error_at(const ts_json_doc *doc, int node, int key_pos, const char *what, char *err, const char *fmt,
                     va_list ap) {
  char msg[TS_ERR_LEN];
  vsnprintf(msg, sizeof(msg), fmt, ap);
  const ts_json_node *n = &doc->nodes[node];
  int line, col;
  ts_json_where(doc, key_pos ? n->key_off : n->off, &line, &col);
  return ts_error(err, TS_EFORMAT, "%s:%d:%d: %s: %s", doc->name, line, col, what, msg);
}
