/* test_catalogue.c - the aerial catalogue (server/cli/catalogue.c): good
 * catalogues with and without lines, paths joined with the catalogue's
 * directory, the defaults, and every refusal with its file:line:col. The
 * JSON grammar itself is test_json.c's. */
#include <stdio.h>
#include <sys/stat.h>

#include "catalogue.h"
#include "error.h"
#include "json.h"
#include "ts_test.h"

/* The issue's example, one field per line where the tests point. */
static const char example[] =
    "{\"classes\": [\n"
    "   {\"id\": 1, \"name\": \"forest\", \"reference\": \"forest.png\", \"kind\": \"stochastic\", \"usage_weight\": 1.0},\n"
    "   {\"id\": 2, \"name\": \"town\",   \"reference\": \"town.png\",   \"kind\": \"structured\", \"usage_weight\": 0.2}],\n"
    " \"lines\": {\"raster\": \"roads.png\", \"colours\": {\"255\": [90, 90, 90]}}}\n";

static ts_catalogue *cat_new(void) {
  ts_catalogue *c = malloc(sizeof(*c));
  assert_non_null(c);
  return c;
}

/* text must be refused with code and exactly the message want. */
static void refused(const char *text, int code, const char *want) {
  ts_catalogue *c = cat_new();
  char err[TS_ERR_LEN] = "";
  int rc = ts_catalogue_parse(text, strlen(text), "cat.json", "/data", c, err);
  if (rc != code || strcmp(err, want) != 0)
    fail_msg("%s\n  gave %d \"%s\"\n  want %d \"%s\"", text, rc, err, code, want);
  assert_int_equal(c->nclass, 0); /* nothing half-filled */
  assert_int_equal(c->ncolours, 0);
  free(c);
}

/* One class with the given fields (after "id": 1), refused with want. */
static void class_refused(const char *fields, const char *want) {
  char text[512];
  snprintf(text, sizeof(text), "{\"classes\": [{\"id\": 1, %s}]}", fields);
  refused(text, TS_EFORMAT, want);
}

/* Lines with the given colours object, refused with want. */
static void colours_refused(const char *colours, const char *want) {
  char text[512];
  snprintf(text, sizeof(text),
           "{\"classes\": [{\"id\": 1, \"name\": \"f\", \"reference\": \"f.png\"}], "
           "\"lines\": {\"raster\": \"r.png\", \"colours\": %s}}",
           colours);
  refused(text, TS_EFORMAT, want);
}

/* --- good catalogues ------------------------------------------------------------ */

static void the_issue_example_parses(void **state) {
  (void)state;
  ts_catalogue *c = cat_new();
  char err[TS_ERR_LEN];
  assert_int_equal(ts_catalogue_parse(example, strlen(example), "cat.json", "/data/aerial", c, err), 0);
  assert_int_equal(c->nclass, 2);
  assert_int_equal(c->cls[0].id, 1);
  assert_string_equal(c->cls[0].name, "forest");
  assert_string_equal(c->cls[0].reference, "/data/aerial/forest.png");
  assert_int_equal(c->cls[0].kind, TS_CAT_STOCHASTIC);
  assert_true(c->cls[0].usage_weight == 1.0);
  assert_int_equal(c->cls[0].line, 2);
  assert_int_equal(c->cls[0].col, 45);
  assert_int_equal(c->cls[1].id, 2);
  assert_string_equal(c->cls[1].name, "town");
  assert_string_equal(c->cls[1].reference, "/data/aerial/town.png");
  assert_int_equal(c->cls[1].kind, TS_CAT_STRUCTURED);
  assert_true(c->cls[1].usage_weight == 0.2);
  assert_int_equal(c->has_lines, 1);
  assert_string_equal(c->line_raster, "/data/aerial/roads.png");
  assert_int_equal(c->raster_line, 4);
  assert_int_equal(c->raster_col, 22);
  assert_int_equal(c->ncolours, 1);
  assert_int_equal(c->colour[0].value, 255);
  assert_memory_equal(c->colour[0].rgb, ((uint8_t[]){90, 90, 90}), 3);
  free(c);
}

static void lines_are_optional_and_defaults_follow_the_kind(void **state) {
  (void)state;
  const char *text = "{\"classes\": [{\"id\": 0, \"name\": \"water\", \"reference\": \"w.png\"},\n"
                     "  {\"id\": 65535, \"name\": \"Ortslage \u00fc\", \"reference\": \"o.png\", \"kind\": \"structured\"},\n"
                     "  {\"id\": 7, \"name\": \"sand\", \"reference\": \"s.png\", \"usage_weight\": 0}]}";
  ts_catalogue *c = cat_new();
  char err[TS_ERR_LEN];
  assert_int_equal(ts_catalogue_parse(text, strlen(text), "cat.json", "", c, err), 0);
  assert_int_equal(c->nclass, 3);
  assert_int_equal(c->has_lines, 0);
  assert_int_equal(c->ncolours, 0);
  assert_int_equal(c->cls[0].kind, TS_CAT_STOCHASTIC);
  assert_true(c->cls[0].usage_weight == TS_CAT_STOCHASTIC_WEIGHT);
  assert_int_equal(c->cls[1].id, 65535);
  assert_string_equal(c->cls[1].name, "Ortslage \xC3\xBC");
  assert_true(c->cls[1].usage_weight == TS_CAT_STRUCTURED_WEIGHT);
  assert_true(c->cls[2].usage_weight == 0.0);
  assert_string_equal(c->cls[0].reference, "w.png"); /* no base directory: as given */
  assert_string_equal(ts_cat_kind_name(c->cls[1].kind), "structured");
  assert_string_equal(ts_cat_kind_name(c->cls[0].kind), "stochastic");
  free(c);
}

static void paths_join_the_catalogue_directory_unless_absolute(void **state) {
  (void)state;
  const char *text = "{\"classes\": [{\"id\": 1, \"name\": \"a\", \"reference\": \"refs/a.png\"},"
                     " {\"id\": 2, \"name\": \"b\", \"reference\": \"/abs/b.png\"}],"
                     " \"lines\": {\"raster\": \"../roads.tif\", \"colours\": {\"1\": 0}}}";
  static const struct {
    const char *dir, *a, *b, *raster;
  } cases[] = {
      {"/cat", "/cat/refs/a.png", "/abs/b.png", "/cat/../roads.tif"},
      {"/cat/", "/cat/refs/a.png", "/abs/b.png", "/cat/../roads.tif"},
      {"/", "/refs/a.png", "/abs/b.png", "/../roads.tif"},
      {"rel/dir", "rel/dir/refs/a.png", "/abs/b.png", "rel/dir/../roads.tif"},
      {NULL, "refs/a.png", "/abs/b.png", "../roads.tif"},
  };
  for (size_t i = 0; i < sizeof(cases) / sizeof(cases[0]); i++) {
    ts_catalogue *c = cat_new();
    char err[TS_ERR_LEN];
    assert_int_equal(ts_catalogue_parse(text, strlen(text), "cat.json", cases[i].dir, c, err), 0);
    assert_string_equal(c->cls[0].reference, cases[i].a);
    assert_string_equal(c->cls[1].reference, cases[i].b);
    assert_string_equal(c->line_raster, cases[i].raster);
    free(c);
  }
}

static void colours_take_triples_and_grey_levels(void **state) {
  (void)state;
  const char *text = "{\"lines\": {\"colours\": {\"255\": [90, 91, 92], \"128\": 120, \"0\": [0, 0, 0], \"65535\": 255},"
                     " \"raster\": \"r.png\"}, \"classes\": [{\"id\": 1, \"name\": \"f\", \"reference\": \"f.png\"}]}";
  ts_catalogue *c = cat_new();
  char err[TS_ERR_LEN];
  assert_int_equal(ts_catalogue_parse(text, strlen(text), "cat.json", "", c, err), 0);
  assert_int_equal(c->ncolours, 4);
  static const struct {
    uint32_t value;
    uint8_t rgb[3];
  } want[] = {{255, {90, 91, 92}}, {128, {120, 120, 120}}, {0, {0, 0, 0}}, {65535, {255, 255, 255}}};
  for (int i = 0; i < 4; i++) {
    assert_int_equal(c->colour[i].value, want[i].value);
    assert_memory_equal(c->colour[i].rgb, want[i].rgb, 3);
  }
  free(c);
}

static void the_limits_are_inclusive(void **state) {
  (void)state;
  /* 64 classes, 256 colours, a 63-byte name, usage weight 100. */
  size_t cap = 64 * 200 + 256 * 40 + 256;
  char *text = malloc(cap);
  assert_non_null(text);
  size_t n = (size_t)snprintf(text, cap, "{\"classes\": [");
  for (int i = 0; i < TS_CAT_MAX_CLASSES; i++)
    n += (size_t)snprintf(text + n, cap - n, "%s{\"id\": %d, \"name\": \"%063d\", \"reference\": \"r.png\", "
                          "\"usage_weight\": 100}", i ? ", " : "", i, i);
  n += (size_t)snprintf(text + n, cap - n, "], \"lines\": {\"raster\": \"r.png\", \"colours\": {");
  for (int i = 0; i < TS_CAT_MAX_COLOURS; i++)
    n += (size_t)snprintf(text + n, cap - n, "%s\"%d\": [%d, 0, 255]", i ? ", " : "", i * 7, i);
  n += (size_t)snprintf(text + n, cap - n, "}}}");
  ts_catalogue *c = cat_new();
  char err[TS_ERR_LEN];
  int rc = ts_catalogue_parse(text, n, "cat.json", "", c, err);
  if (rc != 0) fail_msg("%s", err);
  assert_int_equal(c->nclass, TS_CAT_MAX_CLASSES);
  assert_int_equal(c->ncolours, TS_CAT_MAX_COLOURS);
  assert_int_equal(strlen(c->cls[63].name), 63);
  assert_true(c->cls[63].usage_weight == 100.0);
  assert_int_equal(c->colour[255].value, 255 * 7);
  free(c);
  free(text);
}

/* --- refusals: the file ------------------------------------------------------------ */

static void bad_json_is_placed_by_line_and_column(void **state) {
  (void)state;
  refused("{\"classes\": [\n  {\"id\": 1, \"name\": \"forest\",}\n]}", TS_EFORMAT,
          "cat.json:2:29: a trailing comma before '}' is not allowed");
  refused("{\"classes\": [\n  {\"id\": 1 \"name\": \"forest\"}]}", TS_EFORMAT,
          "cat.json:2:12: expected ',' or '}' after a member of the object opened at 2:3, got '\"'");
  refused("{\"classes\": [{\"id\": 1, \"name\": \"a\\xb\"}]}", TS_EFORMAT,
          "cat.json:1:34: invalid escape: a backslash followed by 'x' (valid: \\\" \\\\ \\/ \\b \\f \\n \\r \\t \\uHHHH)");
  refused("{\"classes\": [{\"id\": 1, \"name\": \"\xC3(\"}]}", TS_EFORMAT,
          "cat.json:1:33: invalid UTF-8 in a string (byte 0xc3)");
  refused("{\"classes\": [{\"id\": 1e999}]}", TS_EFORMAT,
          "cat.json:1:21: the number 1e999 is too large (beyond a double's range)");
  refused("", TS_EFORMAT, "cat.json:1:1: the text is empty: expected a JSON value");
  refused("{\"classes\": [{\"id\": 1,\n \"id\": 2}]}", TS_EFORMAT, "cat.json:2:2: duplicate key \"id\" (first given at 1:15)");
}

static void deep_nesting_is_refused(void **state) {
  (void)state;
  char text[256];
  int n = snprintf(text, sizeof(text), "{\"classes\": ");
  for (int i = 0; i < 70; i++) text[n++] = '[';
  text[n] = '\0';
  refused(text, TS_ELIMIT, "cat.json:1:76: containers nested more than 64 deep");
}

static void the_top_level_is_checked(void **state) {
  (void)state;
  refused("[]", TS_EFORMAT,
          "cat.json:1:1: catalogue: must be an object {\"classes\": [...], \"lines\": {...}}, got an array");
  refused("{}", TS_EFORMAT, "cat.json:1:1: catalogue: no \"classes\" (the list of classes)");
  refused("{\"classes\": [{\"id\": 1, \"name\": \"f\", \"reference\": \"f.png\"}], \"line\": {}}", TS_EFORMAT,
          "cat.json:1:61: catalogue: unknown key \"line\" (known: \"classes\", \"lines\"); did you mean \"lines\"?");
  refused("{\"classes\": {}}", TS_EFORMAT,
          "cat.json:1:13: classes: must be a list of 1..64 classes [{\"id\": ..., ...}, ...], got an object");
  refused("{\"classes\": []}", TS_EFORMAT,
          "cat.json:1:13: classes: must be a list of 1..64 classes [{\"id\": ..., ...}, ...], got an empty one");
  refused("{\"classes\": \"forest\"}", TS_EFORMAT,
          "cat.json:1:13: classes: must be a list of 1..64 classes [{\"id\": ..., ...}, ...], got \"forest\"");
}

static void too_many_classes_are_refused(void **state) {
  (void)state;
  char text[65 * 80 + 64];
  size_t n = (size_t)snprintf(text, sizeof(text), "{\"classes\": [");
  for (int i = 0; i <= TS_CAT_MAX_CLASSES; i++)
    n += (size_t)snprintf(text + n, sizeof(text) - n, "%s{\"id\": %d, \"name\": \"c%d\", \"reference\": \"r\"}",
                          i ? "," : "", i, i);
  snprintf(text + n, sizeof(text) - n, "]}");
  refused(text, TS_EFORMAT, "cat.json:1:13: classes: 65 classes, more than the 64 a catalogue may hold");
}

/* --- refusals: classes ---------------------------------------------------------- */

static void a_class_is_an_object_with_its_fields(void **state) {
  (void)state;
  refused("{\"classes\": [\"forest\"]}", TS_EFORMAT,
          "cat.json:1:14: class 1: a class must be an object {\"id\": ..., \"name\": ..., \"reference\": ...}, "
          "got \"forest\"");
  refused("{\"classes\": [{\"name\": \"forest\", \"reference\": \"f.png\"}]}", TS_EFORMAT,
          "cat.json:1:14: class 1 (\"forest\"): no \"id\" (a whole number 0..65535, the class's value in the class map)");
  class_refused("\"reference\": \"f.png\"", "cat.json:1:14: class 1: no \"name\" (a non-empty string)");
  class_refused("\"name\": \"forest\"",
                "cat.json:1:14: class 1 (\"forest\"): no \"reference\" (the path of its reference texture)");
}

static void unknown_class_keys_are_named_with_a_suggestion(void **state) {
  (void)state;
  class_refused("\"name\": \"forest\", \"reference\": \"f.png\", \"usage_wieght\": 0.5",
                "cat.json:1:64: class 1 (\"forest\"): unknown key \"usage_wieght\" (known: \"id\", \"name\", "
                "\"reference\", \"kind\", \"usage_weight\"); did you mean \"usage_weight\"?");
  class_refused("\"nmae\": \"forest\", \"reference\": \"f.png\"",
                "cat.json:1:24: class 1: unknown key \"nmae\" (known: \"id\", \"name\", \"reference\", \"kind\", "
                "\"usage_weight\"); did you mean \"name\"?");
  class_refused("\"name\": \"forest\", \"reference\": \"f.png\", \"colour\": 3",
                "cat.json:1:64: class 1 (\"forest\"): unknown key \"colour\" (known: \"id\", \"name\", \"reference\", "
                "\"kind\", \"usage_weight\")");
}

static void ids_are_whole_numbers_in_range(void **state) {
  (void)state;
  static const struct {
    const char *id, *got;
  } bad[] = {{"\"1\"", "\"1\""}, {"1.5", "1.5"}, {"-1", "-1"}, {"65536", "65536"}, {"true", "true"},
             {"null", "null"}, {"[1]", "an array"}, {"1e300", "1e300"}};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    char text[256], want[256];
    snprintf(text, sizeof(text), "{\"classes\": [{\"name\": \"f\", \"reference\": \"f.png\", \"id\": %s}]}", bad[i].id);
    snprintf(want, sizeof(want), "cat.json:1:56: class 1 (\"f\"): id must be a whole number 0..65535, got %s",
             bad[i].got);
    refused(text, TS_EFORMAT, want);
  }
}

static void names_are_short_printable_strings(void **state) {
  (void)state;
  class_refused("\"name\": \"\", \"reference\": \"f.png\"",
                "cat.json:1:32: class 1: name must be a non-empty string, got \"\"");
  class_refused("\"name\": 4, \"reference\": \"f.png\"", "cat.json:1:32: class 1: name must be a non-empty string, got 4");
  class_refused("\"name\": \"a\\u0000b\", \"reference\": \"f.png\"",
                "cat.json:1:32: class 1: name holds the control character 0x00");
  class_refused("\"name\": \"a\\nb\", \"reference\": \"f.png\"",
                "cat.json:1:32: class 1: name holds the control character 0x0a");
  char fields[200], want[200];
  snprintf(fields, sizeof(fields), "\"name\": \"%064d\", \"reference\": \"f.png\"", 0);
  snprintf(want, sizeof(want), "cat.json:1:32: class 1: name is 64 bytes long (at most 63)");
  class_refused(fields, want);
}

static void references_are_non_empty_paths_that_fit(void **state) {
  (void)state;
  class_refused("\"name\": \"f\", \"reference\": \"\"",
                "cat.json:1:50: class 1 (\"f\"): reference must be a non-empty path, got \"\"");
  class_refused("\"name\": \"f\", \"reference\": [\"a.png\"]",
                "cat.json:1:50: class 1 (\"f\"): reference must be a non-empty path, got an array");
  /* A relative path that fits alone but not joined with the directory. */
  size_t n = PATH_MAX - 3;
  char *text = malloc(n + 200);
  assert_non_null(text);
  int k = snprintf(text, 200, "{\"classes\": [{\"id\": 1, \"name\": \"f\", \"reference\": \"");
  memset(text + k, 'a', n);
  snprintf(text + k + n, 200, "\"}]}");
  char want[256];
  snprintf(want, sizeof(want),
           "cat.json:1:50: class 1 (\"f\"): reference: the path joined with /data is too long (%zu bytes, at most %d)",
           n + 6, PATH_MAX - 1);
  refused(text, TS_EFORMAT, want);
  free(text);
}

static void kinds_and_usage_weights_are_checked(void **state) {
  (void)state;
  class_refused("\"name\": \"town\", \"reference\": \"t.png\", \"kind\": \"Structured\"",
                "cat.json:1:70: class 1 (\"town\"): kind must be \"stochastic\" or \"structured\", got \"Structured\"");
  class_refused("\"name\": \"town\", \"reference\": \"t.png\", \"kind\": 1",
                "cat.json:1:70: class 1 (\"town\"): kind must be \"stochastic\" or \"structured\", got 1");
  class_refused("\"name\": \"forest\", \"reference\": \"f.png\", \"usage_weight\": \"high\"",
                "cat.json:1:80: class 1 (\"forest\"): usage_weight must be a number 0..100, got \"high\"");
  class_refused("\"name\": \"forest\", \"reference\": \"f.png\", \"usage_weight\": -0.5",
                "cat.json:1:80: class 1 (\"forest\"): usage_weight must be a number 0..100, got -0.5");
  class_refused("\"name\": \"forest\", \"reference\": \"f.png\", \"usage_weight\": 100.01",
                "cat.json:1:80: class 1 (\"forest\"): usage_weight must be a number 0..100, got 100.01");
}

static void ids_and_names_are_unique(void **state) {
  (void)state;
  refused("{\"classes\": [{\"id\": 1, \"name\": \"forest\", \"reference\": \"f.png\"},\n"
          " {\"id\": 2, \"name\": \"water\", \"reference\": \"w.png\"},\n"
          " {\"id\": 1, \"name\": \"town\", \"reference\": \"t.png\"}]}",
          TS_EFORMAT, "cat.json:3:9: class 3 (\"town\"): id 1 is already the id of class 1 (\"forest\")");
  refused("{\"classes\": [{\"id\": 1, \"name\": \"forest\", \"reference\": \"f.png\"},\n"
          " {\"id\": 2, \"name\": \"forest\", \"reference\": \"g.png\"}]}",
          TS_EFORMAT, "cat.json:2:20: class 2 (\"forest\"): the name \"forest\" is already the name of class 1 (id 1)");
}

/* --- refusals: lines ------------------------------------------------------------- */

static void lines_need_a_raster_and_colours(void **state) {
  (void)state;
  const char *cls = "{\"classes\": [{\"id\": 1, \"name\": \"f\", \"reference\": \"f.png\"}], ";
  static const struct {
    const char *lines, *want;
  } bad[] = {
      {"\"lines\": []}", "cat.json:1:70: lines: must be an object {\"raster\": ..., \"colours\": {...}} or "
                         "{\"vector\": ..., \"rules\": [...], \"colours\": {...}}, got an array"},
      {"\"lines\": {\"colours\": {\"1\": 2}}}", "cat.json:1:70: lines: no \"raster\" (the path of the line raster)"},
      {"\"lines\": {\"raster\": \"r.png\"}}",
       "cat.json:1:70: lines: no \"colours\" (pixel values to colours, e.g. {\"255\": [90, 90, 90]})"},
      {"\"lines\": {\"raster\": 5, \"colours\": {\"1\": 2}}}",
       "cat.json:1:81: lines: raster must be a non-empty path, got 5"},
      {"\"lines\": {\"raster\": \"r.png\", \"colors\": {\"1\": 2}}}",
       "cat.json:1:90: lines: unknown key \"colors\" (known: \"raster\", \"colours\"); did you mean \"colours\"?"},
  };
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    char text[512];
    snprintf(text, sizeof(text), "%s%s", cls, bad[i].lines);
    refused(text, TS_EFORMAT, bad[i].want);
  }
}

/* A vector layer's lines: its rules read as gis.h's JSON form, each rule's
 * value given a colour; the raster's keys and the rules' keys not mixed. */
static void vector_lines_take_rules_with_colours(void **state) {
  (void)state;
  const char *cls = "{\"classes\": [{\"id\": 1, \"name\": \"f\", \"reference\": \"f.png\"}], ";
  ts_catalogue *c = calloc(1, sizeof(*c));
  char err[TS_ERR_LEN], text[512];
  snprintf(text, sizeof(text), "%s\"lines\": {\"vector\": \"roads.geojson\", \"field\": \"kind\", \"rules\": "
           "[{\"match\": \"road\", \"value\": 255, \"width\": 6}], \"colours\": {\"255\": [90, 90, 90]}}}", cls);
  assert_int_equal(ts_catalogue_parse(text, strlen(text), "cat.json", "/d", c, err), 0);
  assert_int_equal(c->has_lines, 1);
  assert_int_equal(c->line_vector, 1);
  assert_string_equal(c->line_raster, "/d/roads.geojson");
  free(c);
  static const struct {
    const char *lines, *want;
  } bad[] = {
      {"\"lines\": {\"vector\": \"r.geojson\", \"rules\": [{\"value\": 128, \"width\": 2}], \"colours\": {\"255\": 1}}}",
       "cat.json:1:70: lines: rule 1 (\"\") draws value 128, which \"colours\" gives no colour; add \"128\": [R, G, B]"},
      {"\"lines\": {\"vector\": \"r.geojson\", \"raster\": \"r.png\", \"colours\": {\"1\": 2}}}",
       "cat.json:1:70: lines: give either \"raster\" (a line raster) or \"vector\" (a vector layer), not both"},
      {"\"lines\": {\"raster\": \"r.png\", \"rules\": [], \"colours\": {\"1\": 2}}}",
       "cat.json:1:90: lines: unknown key \"rules\" (known: \"raster\", \"colours\")"},
  };
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    snprintf(text, sizeof(text), "%s%s", cls, bad[i].lines);
    refused(text, TS_EFORMAT, bad[i].want);
  }
}

static void colour_keys_are_pixel_values(void **state) {
  (void)state;
  const char *keys[] = {"abc", "0255", "65536", "-1", "+1", " 1", "", "1.0", "123456"};
  for (size_t i = 0; i < sizeof(keys) / sizeof(keys[0]); i++) {
    char colours[64], want[256];
    snprintf(colours, sizeof(colours), "{\"%s\": 1}", keys[i]);
    snprintf(want, sizeof(want),
             "cat.json:1:102: lines: the key \"%s\" is not a pixel value of the line raster (0..65535 in decimal, "
             "no sign or leading zero)",
             keys[i]);
    colours_refused(colours, want);
  }
}

static void colour_values_are_rgb_or_grey(void **state) {
  (void)state;
  colours_refused("{}", "cat.json:1:101: lines: colours must map pixel values to colours, e.g. {\"255\": [90, 90, 90]}, "
                        "got an empty object (no line would be drawn)");
  colours_refused("[[255, 1, 2, 3]]", "cat.json:1:101: lines: colours must map pixel values to colours, e.g. "
                                      "{\"255\": [90, 90, 90]}, got an array");
  colours_refused("{\"255\": [90, 90, 90, 255]}",
                  "cat.json:1:109: lines: colours \"255\": a colour is [R, G, B] (each 0..255) or one grey level "
                  "0..255, got an array (no alpha: lines are drawn opaque)");
  colours_refused("{\"255\": [90, 90]}", "cat.json:1:109: lines: colours \"255\": a colour is [R, G, B] (each 0..255) "
                                         "or one grey level 0..255, got an array of the wrong length");
  colours_refused("{\"255\": \"grey\"}", "cat.json:1:109: lines: colours \"255\": a colour is [R, G, B] (each 0..255) "
                                         "or one grey level 0..255, got \"grey\"");
  colours_refused("{\"255\": [90, 256, 90]}",
                  "cat.json:1:114: lines: colours \"255\": green must be a whole number 0..255, got 256");
  colours_refused("{\"255\": [90, 90, 0.5]}",
                  "cat.json:1:118: lines: colours \"255\": blue must be a whole number 0..255, got 0.5");
  colours_refused("{\"1\": 1, \"255\": -3}",
                  "cat.json:1:117: lines: colours \"255\": a grey level must be a whole number 0..255, got -3");
  colours_refused("{\"255\": 1, \"255\": 2}", "cat.json:1:112: duplicate key \"255\" (first given at 1:102)");
}

static void too_many_colours_are_refused(void **state) {
  (void)state;
  char colours[(TS_CAT_MAX_COLOURS + 1) * 12 + 8];
  size_t n = (size_t)snprintf(colours, sizeof(colours), "{");
  for (int i = 0; i <= TS_CAT_MAX_COLOURS; i++)
    n += (size_t)snprintf(colours + n, sizeof(colours) - n, "%s\"%d\": 1", i ? "," : "", i);
  snprintf(colours + n, sizeof(colours) - n, "}");
  char text[sizeof(colours) + 200];
  snprintf(text, sizeof(text),
           "{\"classes\": [{\"id\": 1, \"name\": \"f\", \"reference\": \"f.png\"}], "
           "\"lines\": {\"raster\": \"r.png\", \"colours\": %s}}",
           colours);
  refused(text, TS_EFORMAT, "cat.json:1:101: lines: 257 colours, more than the 256 a catalogue may hold");
}

/* --- ts_catalogue_load --------------------------------------------------------------- */

typedef struct {
  char dir[32];
  char path[96];
} fixture;

static void put(const char *dir, const char *name, const char *text) {
  char path[128];
  snprintf(path, sizeof(path), "%s/%s", dir, name);
  FILE *f = fopen(path, "wb");
  assert_non_null(f);
  assert_int_equal(fwrite(text, 1, strlen(text), f), strlen(text));
  assert_int_equal(fclose(f), 0);
}

static void fixture_make(fixture *fx, const char *catalogue) {
  snprintf(fx->dir, sizeof(fx->dir), "/tmp/ts-cat-XXXXXX");
  assert_non_null(mkdtemp(fx->dir));
  snprintf(fx->path, sizeof(fx->path), "%s/cat.json", fx->dir);
  put(fx->dir, "cat.json", catalogue);
}

static void fixture_remove(fixture *fx) {
  const char *names[] = {"cat.json", "forest.png", "town.png", "roads.png"};
  char path[128];
  for (size_t i = 0; i < sizeof(names) / sizeof(names[0]); i++) {
    snprintf(path, sizeof(path), "%s/%s", fx->dir, names[i]);
    unlink(path);
  }
  snprintf(path, sizeof(path), "%s/sub", fx->dir);
  rmdir(path);
  assert_int_equal(rmdir(fx->dir), 0);
}

static void load_joins_the_file_directory(void **state) {
  (void)state;
  fixture fx;
  fixture_make(&fx, example);
  put(fx.dir, "forest.png", "x");
  put(fx.dir, "town.png", "x");
  put(fx.dir, "roads.png", "x");
  ts_catalogue *c = cat_new();
  char err[TS_ERR_LEN], want[128];
  int rc = ts_catalogue_load(fx.path, c, err);
  if (rc != 0) fail_msg("%s", err);
  snprintf(want, sizeof(want), "%s/forest.png", fx.dir);
  assert_string_equal(c->cls[0].reference, want);
  snprintf(want, sizeof(want), "%s/roads.png", fx.dir);
  assert_string_equal(c->line_raster, want);
  /* A catalogue named without a directory: paths stay relative to it. */
  char cwd[PATH_MAX];
  assert_non_null(getcwd(cwd, sizeof(cwd)));
  assert_int_equal(chdir(fx.dir), 0);
  rc = ts_catalogue_load("cat.json", c, err);
  assert_int_equal(chdir(cwd), 0);
  if (rc != 0) fail_msg("%s", err);
  assert_string_equal(c->cls[1].reference, "town.png");
  free(c);
  fixture_remove(&fx);
}

static void load_names_a_missing_file_where_the_catalogue_gives_it(void **state) {
  (void)state;
  fixture fx;
  fixture_make(&fx, example);
  put(fx.dir, "forest.png", "x");
  put(fx.dir, "roads.png", "x");
  ts_catalogue *c = cat_new();
  char err[TS_ERR_LEN], want[TS_ERR_LEN];
  assert_int_equal(ts_catalogue_load(fx.path, c, err), TS_ENOENT);
  snprintf(want, sizeof(want), "%s:3:45: class 2 (\"town\"): reference: %s/town.png: No such file or directory",
           fx.path, fx.dir);
  assert_string_equal(err, want);
  assert_int_equal(c->nclass, 0);
  /* A directory is not a reference either; nor a line raster. */
  char sub[64];
  snprintf(sub, sizeof(sub), "%s/sub", fx.dir);
  assert_int_equal(mkdir(sub, 0700), 0);
  put(fx.dir, "town.png", "x");
  char roads[80];
  snprintf(roads, sizeof(roads), "%s/roads.png", fx.dir);
  assert_int_equal(unlink(roads), 0);
  assert_int_equal(ts_catalogue_load(fx.path, c, err), TS_ENOENT);
  snprintf(want, sizeof(want), "%s:4:22: lines: raster: %s/roads.png: No such file or directory", fx.path, fx.dir);
  assert_string_equal(err, want);
  put(fx.dir, "cat.json", "{\"classes\": [{\"id\": 1, \"name\": \"f\", \"reference\": \"sub\"}]}");
  assert_int_equal(ts_catalogue_load(fx.path, c, err), TS_ENOENT);
  snprintf(want, sizeof(want), "%s:1:50: class 1 (\"f\"): reference: %s/sub is not a regular file", fx.path, fx.dir);
  assert_string_equal(err, want);
  free(c);
  fixture_remove(&fx);
}

static void load_refuses_big_or_missing_catalogues(void **state) {
  (void)state;
  fixture fx;
  char *big = malloc(TS_CAT_MAX_BYTES + 2);
  assert_non_null(big);
  memset(big, ' ', TS_CAT_MAX_BYTES + 1);
  big[TS_CAT_MAX_BYTES + 1] = '\0';
  fixture_make(&fx, big);
  free(big);
  ts_catalogue *c = cat_new();
  char err[TS_ERR_LEN], want[TS_ERR_LEN];
  assert_int_equal(ts_catalogue_load(fx.path, c, err), TS_ETOOBIG);
  snprintf(want, sizeof(want), "%s is 1048577 bytes: a catalogue is at most 1048576 (1 MiB); is it the right file?",
           fx.path);
  assert_string_equal(err, want);
  put(fx.dir, "cat.json", "{\"classes\": 1}");
  assert_int_equal(ts_catalogue_load(fx.path, c, err), TS_EFORMAT);
  snprintf(want, sizeof(want), "%s:1:13: classes: must be a list of 1..64 classes [{\"id\": ..., ...}, ...], got 1",
           fx.path);
  assert_string_equal(err, want);
  fixture_remove(&fx);
  assert_int_equal(ts_catalogue_load(fx.path, c, err), TS_EIO);
  assert_non_null(strstr(err, fx.path));
  free(c);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(the_issue_example_parses),
    cmocka_unit_test(lines_are_optional_and_defaults_follow_the_kind),
    cmocka_unit_test(paths_join_the_catalogue_directory_unless_absolute),
    cmocka_unit_test(colours_take_triples_and_grey_levels),
    cmocka_unit_test(the_limits_are_inclusive),
    cmocka_unit_test(bad_json_is_placed_by_line_and_column),
    cmocka_unit_test(deep_nesting_is_refused),
    cmocka_unit_test(the_top_level_is_checked),
    cmocka_unit_test(too_many_classes_are_refused),
    cmocka_unit_test(a_class_is_an_object_with_its_fields),
    cmocka_unit_test(unknown_class_keys_are_named_with_a_suggestion),
    cmocka_unit_test(ids_are_whole_numbers_in_range),
    cmocka_unit_test(names_are_short_printable_strings),
    cmocka_unit_test(references_are_non_empty_paths_that_fit),
    cmocka_unit_test(kinds_and_usage_weights_are_checked),
    cmocka_unit_test(ids_and_names_are_unique),
    cmocka_unit_test(lines_need_a_raster_and_colours),
    cmocka_unit_test(vector_lines_take_rules_with_colours),
    cmocka_unit_test(colour_keys_are_pixel_values),
    cmocka_unit_test(colour_values_are_rgb_or_grey),
    cmocka_unit_test(too_many_colours_are_refused),
    cmocka_unit_test(load_joins_the_file_directory),
    cmocka_unit_test(load_names_a_missing_file_where_the_catalogue_gives_it),
    cmocka_unit_test(load_refuses_big_or_missing_catalogues),
};

TS_TEST_MAIN(tests)
