/* test_json.c - the strict JSON reader (common/json.c): the DOM it builds,
 * the RFC 8259 grammar it holds texts to, and where its messages point. */
#include <stdio.h>

#include "error.h"
#include "json.h"
#include "ts_test.h"

/* Parses text (NUL-terminated here; the reader is given its length). */
static int parse(ts_json_doc *d, const char *text, char *err) {
  return ts_json_parse(d, "t.json", text, strlen(text), 1000, err);
}

/* text must fail with code and exactly the message want. */
static void refused(const char *text, int code, const char *want) {
  ts_json_doc d;
  char err[TS_ERR_LEN] = "";
  int rc = parse(&d, text, err);
  if (rc != code || strcmp(err, want) != 0)
    fail_msg("%s\n  gave %d \"%s\"\n  want %d \"%s\"", text, rc, err, code, want);
}

/* text must parse; its root's type is returned, the doc freed. */
static ts_json_type accepted(const char *text) {
  ts_json_doc d;
  char err[TS_ERR_LEN] = "";
  int rc = parse(&d, text, err);
  if (rc != 0) fail_msg("%s refused: %s", text, err);
  ts_json_type t = d.nodes[0].type;
  ts_json_free(&d);
  return t;
}

/* --- the DOM ------------------------------------------------------------------ */

static void dom_links_members_in_order(void **state) {
  (void)state;
  const char *text = "{\"a\": [1, -2.5e1, true, false, null], \"b\": {\"c\": \"x\"}, \"d\": []}";
  ts_json_doc d;
  char err[TS_ERR_LEN];
  assert_int_equal(parse(&d, text, err), 0);
  assert_int_equal(d.nodes[0].type, TS_JSON_OBJECT);
  assert_int_equal(d.nodes[0].count, 3);
  int a = ts_json_member(&d, 0, "a"), b = ts_json_member(&d, 0, "b"), e = ts_json_member(&d, 0, "d");
  assert_true(a > 0 && b > a && e > b);
  assert_int_equal(ts_json_member(&d, 0, "z"), -1);
  assert_int_equal(d.nodes[a].type, TS_JSON_ARRAY);
  assert_int_equal(d.nodes[a].count, 5);
  static const ts_json_type want[] = {TS_JSON_NUMBER, TS_JSON_NUMBER, TS_JSON_TRUE, TS_JSON_FALSE, TS_JSON_NULL};
  int i = 0;
  for (int m = d.nodes[a].first; m >= 0; m = d.nodes[m].next, i++) assert_int_equal(d.nodes[m].type, want[i]);
  assert_int_equal(i, 5);
  assert_true(d.nodes[d.nodes[a].first].num == 1.0);
  assert_true(d.nodes[d.nodes[d.nodes[a].first].next].num == -25.0);
  int c = ts_json_member(&d, b, "c");
  assert_string_equal(d.nodes[c].str, "x");
  assert_int_equal(d.nodes[e].count, 0);
  assert_int_equal(d.nodes[e].first, -1);
  /* The value's bytes and its key's place. */
  assert_int_equal(d.nodes[a].off, 6);
  assert_int_equal(d.nodes[a].end, 36);
  assert_int_equal(d.nodes[a].key_off, 1);
  ts_json_free(&d);
}

static void scalars_may_be_the_root(void **state) {
  (void)state;
  assert_int_equal(accepted(" 42 "), TS_JSON_NUMBER);
  assert_int_equal(accepted("\"s\""), TS_JSON_STRING);
  assert_int_equal(accepted("null"), TS_JSON_NULL);
  assert_int_equal(accepted("\n[]\r\n"), TS_JSON_ARRAY);
}

static void numbers_follow_the_grammar(void **state) {
  (void)state;
  const char *good[] = {"0", "-0", "12", "-3.25", "1e5", "1E+5", "2e-3", "0.5e0", "123456789012345678901234567890"};
  for (size_t i = 0; i < sizeof(good) / sizeof(good[0]); i++) assert_int_equal(accepted(good[i]), TS_JSON_NUMBER);
  refused("01", TS_EFORMAT, "t.json:1:1: a number may not have leading zeros");
  refused("-01", TS_EFORMAT, "t.json:1:1: a number may not have leading zeros");
  refused("1.", TS_EFORMAT, "t.json:1:3: expected a digit after the decimal point, got the end of the text");
  refused(".5", TS_EFORMAT, "t.json:1:1: expected a value (an object, array, string, number, true, false or null), got '.'");
  refused("+1", TS_EFORMAT, "t.json:1:1: expected a value (an object, array, string, number, true, false or null), got '+'");
  refused("1e", TS_EFORMAT, "t.json:1:3: expected a digit in the exponent, got the end of the text");
  refused("[1e+]", TS_EFORMAT, "t.json:1:5: expected a digit in the exponent, got ']'");
  refused("-x", TS_EFORMAT, "t.json:1:2: expected a digit after '-', got 'x'");
  refused("0x10", TS_EFORMAT, "t.json:1:2: unexpected 'x' after the end of the JSON value");
}

static void huge_numbers_are_refused_tiny_ones_are_zero(void **state) {
  (void)state;
  refused("[1e400]", TS_EFORMAT, "t.json:1:2: the number 1e400 is too large (beyond a double's range)");
  refused("-1e999", TS_EFORMAT, "t.json:1:1: the number -1e999 is too large (beyond a double's range)");
  ts_json_doc d;
  char err[TS_ERR_LEN];
  assert_int_equal(parse(&d, "1e-400", err), 0);
  assert_true(d.nodes[0].num == 0.0);
  ts_json_free(&d);
  /* More digits than are read: refused, not rounded silently. */
  char digits[600];
  memset(digits, '7', sizeof(digits) - 1);
  digits[sizeof(digits) - 1] = '\0';
  refused(digits, TS_EFORMAT, "t.json:1:1: a number of 599 characters (at most 512 are read)");
}

static void literals_are_exact(void **state) {
  (void)state;
  refused("tru", TS_EFORMAT, "t.json:1:1: expected a value (an object, array, string, number, true, false or null), got 'tru'");
  refused("[True]", TS_EFORMAT, "t.json:1:2: expected a value (an object, array, string, number, true, false or null), got 'True'");
  refused("nulls", TS_EFORMAT, "t.json:1:1: expected a value (an object, array, string, number, true, false or null), got 'nulls'");
  refused("NaN", TS_EFORMAT, "t.json:1:1: expected a value (an object, array, string, number, true, false or null), got 'NaN'");
  refused("[Infinity]", TS_EFORMAT, "t.json:1:2: expected a value (an object, array, string, number, true, false or null), got 'Infinity'");
}

/* --- strings ---------------------------------------------------------------------- */

static void escapes_are_decoded(void **state) {
  (void)state;
  ts_json_doc d;
  char err[TS_ERR_LEN];
  assert_int_equal(parse(&d, "\"a\\\"b\\\\c\\/d\\be\\ff\\ng\\rh\\ti\"", err), 0);
  assert_string_equal(d.nodes[0].str, "a\"b\\c/d\be\ff\ng\rh\ti");
  ts_json_free(&d);
  /* \u: one, two and three UTF-8 bytes; a surrogate pair gives four. */
  assert_int_equal(parse(&d, "\"\\u0041\\u00e9\\u20AC\\uD83D\\uDE00\"", err), 0);
  assert_string_equal(d.nodes[0].str, "A\xC3\xA9\xE2\x82\xAC\xF0\x9F\x98\x80");
  assert_int_equal(d.nodes[0].slen, 10);
  ts_json_free(&d);
  /* \u0000 is kept, and counted in the length. */
  assert_int_equal(parse(&d, "\"a\\u0000b\"", err), 0);
  assert_int_equal(d.nodes[0].slen, 3);
  assert_memory_equal(d.nodes[0].str, "a\0b", 4);
  ts_json_free(&d);
}

static void bad_escapes_are_refused(void **state) {
  (void)state;
  refused("\"a\\q\"", TS_EFORMAT,
          "t.json:1:3: invalid escape: a backslash followed by 'q' (valid: \\\" \\\\ \\/ \\b \\f \\n \\r \\t \\uHHHH)");
  refused("\"\\u12G4\"", TS_EFORMAT, "t.json:1:2: \\u must be followed by 4 hex digits");
  refused("\"\\u12\"", TS_EFORMAT, "t.json:1:2: \\u must be followed by 4 hex digits");
  refused("\"\\uD800\"", TS_EFORMAT,
          "t.json:1:2: lone high surrogate \\uD800 (a low surrogate \\uDC00..\\uDFFF must follow)");
  refused("\"\\uD800\\u0041\"", TS_EFORMAT,
          "t.json:1:2: lone high surrogate \\uD800 (a low surrogate \\uDC00..\\uDFFF must follow)");
  refused("\"x\\uDC00\"", TS_EFORMAT,
          "t.json:1:3: lone low surrogate \\uDC00 (it must follow a high surrogate \\uD800..\\uDBFF)");
  refused("\"\\", TS_EFORMAT, "t.json:1:2: unterminated string: the text ends in an escape");
}

static void control_characters_must_be_escaped(void **state) {
  (void)state;
  refused("\"a\tb\"", TS_EFORMAT, "t.json:1:3: control character 0x09 in a string: write it as \\u0009");
  refused("[\"ab\ncd\"]", TS_EFORMAT,
          "t.json:1:2: unterminated string: a line break before its closing '\"' (write it as \\n)");
  refused("{\"a\": \"x", TS_EFORMAT, "t.json:1:7: unterminated string: no closing '\"' for the '\"' here");
}

static void utf8_is_checked(void **state) {
  (void)state;
  assert_int_equal(accepted("\"gr\xC3\xBCn \xE6\xA3\xAE \xF0\x9F\x8C\xB2\""), TS_JSON_STRING);
  const char *bad[] = {
      "\"\x80\"",             /* a stray continuation byte */
      "\"\xC3\"",             /* cut short */
      "\"\xC0\xAF\"",         /* overlong '/' */
      "\"\xE0\x80\xAF\"",     /* overlong, three bytes */
      "\"\xED\xA0\x80\"",     /* an encoded surrogate */
      "\"\xF4\x90\x80\x80\"", /* above U+10FFFF */
      "\"\xFF\"",
  };
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    char want[64];
    snprintf(want, sizeof(want), "t.json:1:2: invalid UTF-8 in a string (byte 0x%02x)", (unsigned char)bad[i][1]);
    refused(bad[i], TS_EFORMAT, want);
  }
  /* Outside strings only ASCII is JSON. */
  refused("[\xC3\xA9]", TS_EFORMAT,
          "t.json:1:2: expected a value (an object, array, string, number, true, false or null), got byte 0xc3");
}

static void a_byte_order_mark_is_skipped(void **state) {
  (void)state;
  assert_int_equal(accepted("\xEF\xBB\xBF{}"), TS_JSON_OBJECT);
  refused("\xEF\xBB\xBF", TS_EFORMAT, "t.json:1:2: the text is empty: expected a JSON value");
}

/* --- structure -------------------------------------------------------------------- */

static void structure_errors_say_what_was_expected(void **state) {
  (void)state;
  refused("", TS_EFORMAT, "t.json:1:1: the text is empty: expected a JSON value");
  refused(" \n ", TS_EFORMAT, "t.json:2:2: the text is empty: expected a JSON value");
  refused("[1, 2", TS_EFORMAT, "t.json:1:6: the text ends inside the array opened at 1:1");
  refused("{\"a\": 1", TS_EFORMAT, "t.json:1:8: the text ends inside the object opened at 1:1");
  refused("{\"a\":", TS_EFORMAT, "t.json:1:6: the text ends inside the object opened at 1:1");
  refused("{\"a\": [1,", TS_EFORMAT, "t.json:1:10: the text ends inside the array opened at 1:7");
  refused("[1 2]", TS_EFORMAT, "t.json:1:4: expected ',' or ']' after a member of the array opened at 1:1, got '2'");
  refused("{\"a\": 1 \"b\": 2}", TS_EFORMAT,
          "t.json:1:9: expected ',' or '}' after a member of the object opened at 1:1, got '\"'");
  refused("{\"a\" 1}", TS_EFORMAT, "t.json:1:6: expected ':' after the key \"a\", got '1'");
  refused("{1: 2}", TS_EFORMAT, "t.json:1:2: expected a key in double quotes, got '1'");
  refused("{'a': 2}", TS_EFORMAT, "t.json:1:2: keys take double quotes (\"), not single ones");
  refused("['a']", TS_EFORMAT, "t.json:1:2: strings take double quotes (\"), not single ones");
  refused("[1] // done", TS_EFORMAT, "t.json:1:5: unexpected '/' after the end of the JSON value");
  refused("[/* x */ 1]", TS_EFORMAT, "t.json:1:2: comments are not allowed in JSON");
  refused("{} {}", TS_EFORMAT, "t.json:1:4: unexpected '{' after the end of the JSON value");
  refused("[1]]", TS_EFORMAT, "t.json:1:4: unexpected ']' after the end of the JSON value");
  refused("[\x01]", TS_EFORMAT,
          "t.json:1:2: expected a value (an object, array, string, number, true, false or null), got byte 0x01");
}

static void trailing_commas_are_refused(void **state) {
  (void)state;
  refused("[1, 2, ]", TS_EFORMAT, "t.json:1:6: a trailing comma before ']' is not allowed");
  refused("{\"a\": 1,\n}", TS_EFORMAT, "t.json:1:8: a trailing comma before '}' is not allowed");
  refused("[,]", TS_EFORMAT, "t.json:1:2: expected a value (an object, array, string, number, true, false or null), got ','");
  refused("{,}", TS_EFORMAT, "t.json:1:2: expected a key in double quotes, got ','");
}

static void duplicate_keys_are_refused(void **state) {
  (void)state;
  refused("{\"a\": 1, \"b\": 2, \"a\": 3}", TS_EFORMAT, "t.json:1:18: duplicate key \"a\" (first given at 1:2)");
  /* The earliest repeat is named, with its key's first place. */
  refused("{\"b\": 1,\n \"a\": 1,\n \"a\": 2,\n \"b\": 3, \"a\": 4}", TS_EFORMAT,
          "t.json:3:2: duplicate key \"a\" (first given at 2:2)");
  /* Keys that differ only after a \u0000 differ; in different objects they may repeat. */
  assert_int_equal(accepted("{\"a\\u0000x\": 1, \"a\\u0000y\": 2, \"o\": {\"a\": 1}, \"p\": {\"a\": 1}}"),
                   TS_JSON_OBJECT);
  /* Escaped and plain spellings of one key are one key. */
  refused("{\"ab\": 1, \"a\\u0062\": 2}", TS_EFORMAT, "t.json:1:11: duplicate key \"ab\" (first given at 1:2)");
}

static void nesting_is_limited_without_recursion(void **state) {
  (void)state;
  char deep[2 * TS_JSON_MAX_DEPTH + 3];
  /* TS_JSON_MAX_DEPTH levels are fine. */
  memset(deep, '[', TS_JSON_MAX_DEPTH);
  memset(deep + TS_JSON_MAX_DEPTH, ']', TS_JSON_MAX_DEPTH);
  deep[2 * TS_JSON_MAX_DEPTH] = '\0';
  assert_int_equal(accepted(deep), TS_JSON_ARRAY);
  /* One more is not. */
  memset(deep, '[', TS_JSON_MAX_DEPTH + 1);
  memset(deep + TS_JSON_MAX_DEPTH + 1, ']', TS_JSON_MAX_DEPTH + 1);
  deep[2 * TS_JSON_MAX_DEPTH + 2] = '\0';
  refused(deep, TS_ELIMIT, "t.json:1:65: containers nested more than 64 deep");
  /* A million open brackets: refused at the limit, quickly, no stack used. */
  size_t n = 1000000;
  char *huge = malloc(n + 1);
  assert_non_null(huge);
  memset(huge, '{', n);
  for (size_t i = 0; i < n; i += 2) huge[i] = '[';
  huge[n] = '\0';
  ts_json_doc d;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_json_parse(&d, "t.json", huge, n, 1000, err), TS_EFORMAT); /* "{[" : a key is due */
  memset(huge, '[', n);
  assert_int_equal(ts_json_parse(&d, "t.json", huge, n, 1000, err), TS_ELIMIT);
  free(huge);
}

static void the_node_budget_holds(void **state) {
  (void)state;
  ts_json_doc d;
  char err[TS_ERR_LEN];
  const char *text = "[1, 2, 3, 4]";
  assert_int_equal(ts_json_parse(&d, "t.json", text, strlen(text), 5, err), 0);
  ts_json_free(&d);
  assert_int_equal(ts_json_parse(&d, "t.json", text, strlen(text), 4, err), TS_ELIMIT);
  assert_string_equal(err, "t.json:1:11: more than 4 values: too many for this reader");
  assert_int_equal(ts_json_parse(&d, "t.json", text, strlen(text), 0, err), TS_EINVAL);
}

static void never_reads_past_len(void **state) {
  (void)state;
  /* The text goes on past len; the reader must stop at len. */
  const char *text = "[1, 2]garbage";
  ts_json_doc d;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_json_parse(&d, "t.json", text, 6, 10, err), 0);
  ts_json_free(&d);
  assert_int_equal(ts_json_parse(&d, "t.json", text, 5, 10, err), TS_EFORMAT);
  assert_string_equal(err, "t.json:1:6: the text ends inside the array opened at 1:1");
  assert_int_equal(ts_json_parse(&d, "t.json", "\"abc\"", 4, 10, err), TS_EFORMAT);
  assert_int_equal(ts_json_parse(&d, "t.json", "tru", 2, 10, err), TS_EFORMAT);
  assert_int_equal(ts_json_parse(&d, "t.json", "\"\\u00e9\"", 5, 10, err), TS_EFORMAT);
}

/* --- positions and quoting ------------------------------------------------------ */

static void columns_count_characters_lines_count_newlines(void **state) {
  (void)state;
  /* "é" is two bytes and one column; a tab is one column. */
  refused("{\"n\u00e9\": 1,\n\t\"x\": tru}", TS_EFORMAT,
          "t.json:2:7: expected a value (an object, array, string, number, true, false or null), got 'tru'");
  refused("[\r\n1,\r\n  x]", TS_EFORMAT,
          "t.json:3:3: expected a value (an object, array, string, number, true, false or null), got 'x'");
}

static void quote_shows_the_value_text(void **state) {
  (void)state;
  ts_json_doc d;
  char err[TS_ERR_LEN], q[16];
  const char *text = "[\"high\", -1.5e2, true, {}, [], \"a very long string indeed\", \"\u00e9\u00e9\u00e9\u00e9\u00e9\u00e9\u00e9\"]";
  assert_int_equal(parse(&d, text, err), 0);
  const char *want[] = {"\"high\"", "-1.5e2", "true", "an object", "an array", "\"a very long...", "\"\u00e9\u00e9\u00e9\u00e9\u00e9..."};
  int i = 0;
  for (int m = d.nodes[0].first; m >= 0; m = d.nodes[m].next, i++) {
    ts_json_quote(&d, m, q, sizeof(q));
    assert_string_equal(q, want[i]);
  }
  ts_json_free(&d);
  assert_string_equal(ts_json_type_name(TS_JSON_STRING), "a string");
  assert_string_equal(ts_json_type_name(TS_JSON_TRUE), "a boolean");
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(dom_links_members_in_order),
    cmocka_unit_test(scalars_may_be_the_root),
    cmocka_unit_test(numbers_follow_the_grammar),
    cmocka_unit_test(huge_numbers_are_refused_tiny_ones_are_zero),
    cmocka_unit_test(literals_are_exact),
    cmocka_unit_test(escapes_are_decoded),
    cmocka_unit_test(bad_escapes_are_refused),
    cmocka_unit_test(control_characters_must_be_escaped),
    cmocka_unit_test(utf8_is_checked),
    cmocka_unit_test(a_byte_order_mark_is_skipped),
    cmocka_unit_test(structure_errors_say_what_was_expected),
    cmocka_unit_test(trailing_commas_are_refused),
    cmocka_unit_test(duplicate_keys_are_refused),
    cmocka_unit_test(nesting_is_limited_without_recursion),
    cmocka_unit_test(the_node_budget_holds),
    cmocka_unit_test(never_reads_past_len),
    cmocka_unit_test(columns_count_characters_lines_count_newlines),
    cmocka_unit_test(quote_shows_the_value_text),
};
TS_TEST_MAIN(tests)
