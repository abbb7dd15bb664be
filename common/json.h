/* json.h - a strict JSON (RFC 8259) reader for small configuration files
 * such as the aerial catalogue (server/cli/catalogue.h).
 *
 * The whole text is parsed into a small DOM: an array of nodes, children
 * linked by index, strings decoded into one pool. The parser keeps its own
 * stack (no recursion), nests at most TS_JSON_MAX_DEPTH containers, takes
 * at most max_nodes values, never reads past len and never aborts: any bad
 * input is a TS_EFORMAT (or TS_ELIMIT) with a message
 * "NAME:LINE:COL: what was expected, what was found".
 *
 * Strict means: one value and white space only (no comments, no trailing
 * commas, no single quotes, no NaN or Infinity, no leading zeros), the text
 * is valid UTF-8 (no overlong forms, no encoded surrogates, nothing above
 * U+10FFFF), control characters in strings are escaped, \u escapes are
 * decoded to UTF-8 with surrogate pairs joined and lone surrogates refused,
 * and the keys of an object are unique. Two things are allowed beyond the
 * grammar, as RFC 8259 permits: a leading UTF-8 byte order mark is skipped,
 * and numbers too small for a double become 0 (numbers too large for one
 * are refused).
 *
 * Positions: LINE counts '\n' from 1; COL counts characters (UTF-8 code
 * points, a tab is one) from 1, as editors show them. */
#ifndef TS_JSON_H
#define TS_JSON_H

#include <stdarg.h>
#include <stddef.h>

#define TS_JSON_MAX_DEPTH 64

typedef enum {
  TS_JSON_NULL = 0,
  TS_JSON_FALSE,
  TS_JSON_TRUE,
  TS_JSON_NUMBER,
  TS_JSON_STRING,
  TS_JSON_ARRAY,
  TS_JSON_OBJECT
} ts_json_type;

typedef struct {
  ts_json_type type;
  size_t off, end;   /* the value's bytes in the text: [off, end) */
  double num;        /* number: its value */
  const char *str;   /* string: decoded UTF-8, NUL-terminated (in the pool) */
  size_t slen;       /* string: bytes, without the NUL (a \u0000 counts) */
  int count;         /* array, object: members */
  int first;         /* array, object: the first member's node, or -1 */
  int next;          /* the next member of the same parent, or -1 */
  const char *key;   /* member of an object: its key, decoded (else NULL) */
  size_t klen;       /* the key's bytes */
  size_t key_off;    /* where the key's opening quote is */
} ts_json_node;

typedef struct {
  const char *name;    /* what messages call the text, e.g. a file name */
  const char *text;    /* the text parsed (not copied: keep it alive) */
  size_t len;
  ts_json_node *nodes; /* nodes[0] is the root value */
  int nnodes;
  char *pool;          /* decoded strings and keys */
} ts_json_doc;

/* Parses len bytes of text into doc (name for messages; text must stay
 * valid while doc is used). 0, TS_EFORMAT for text that is not one strict
 * JSON value, TS_ELIMIT for nesting over TS_JSON_MAX_DEPTH or more than
 * max_nodes values, TS_ENOMEM. On failure doc holds nothing to free. */
int ts_json_parse(ts_json_doc *doc, const char *name, const char *text, size_t len, int max_nodes,
                  char *err);
void ts_json_free(ts_json_doc *doc);

/* The member of object node obj named key (the node's index), or -1. */
int ts_json_member(const ts_json_doc *doc, int obj, const char *key);

/* Line and column (both from 1, see above) of byte offset off. */
void ts_json_where(const ts_json_doc *doc, size_t off, int *line, int *col);

/* TS_EFORMAT with "NAME:LINE:COL: WHAT: message" in err, placed at node's
 * value (at its key, if key_pos): the readers of JSON files (the catalogue,
 * line rules) say where a problem is the same way. */
int ts_json_error_at(const ts_json_doc *doc, int node, int key_pos, const char *what, char *err, const char *fmt,
                     va_list ap);

/* "a string", "a number", "an object", ... for messages. */
const char *ts_json_type_name(ts_json_type type);

/* The value's own text for messages, e.g. `"high"`, `-3.5`, `true`, and
 * for a container "an array" / "an object"; cut to fit cap with "...". */
void ts_json_quote(const ts_json_doc *doc, int node, char *buf, size_t cap);

#endif
