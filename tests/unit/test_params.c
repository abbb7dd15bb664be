/* test_params.c - the parameter tables (server/engines/param.h): every
 * declared parameter of every engine survives the spec (set off its
 * default, written, read back), a spec value out of range is refused,
 * range problems name the option, and --help's lines come from them; a
 * "0: off, or lo..hi" range (texsyn video's weights) takes 0. */
#include "ts_test.h"

#include "engine.h"
#include "error.h"
#include "jobspec.h"
#include "param.h"
#include "video_guides.h"

static const char *const kEngines[] = {"mrf", "fill", "aerial", "stylize", "energy", "segment"};

/* A valid value of p other than its default, as spec text. */
static void other_value(const ts_param *p, char *buf, size_t cap) {
  switch (p->type) {
  case TS_PARAM_INT: case TS_PARAM_DOUBLE: {
    double def = p->def != NULL ? atof(p->def) : 0;
    double v = def == p->max ? p->min : p->max;
    if ((p->flags & TS_PARAM_MIN_OPEN) && v == p->min) v = (p->min + p->max) / 2;
    snprintf(buf, cap, "%.15g", v);
    break;
  }
  case TS_PARAM_U64: snprintf(buf, cap, "12345678901"); break;
  case TS_PARAM_FLAG: snprintf(buf, cap, "%s", p->def != NULL && strcmp(p->def, "1") == 0 ? "0" : "1"); break;
  case TS_PARAM_SIZE: snprintf(buf, cap, "17x23"); break;
  case TS_PARAM_ENUM: snprintf(buf, cap, "%s", strcmp(p->names[0], p->def) == 0 ? p->names[1] : p->names[0]); break;
  case TS_PARAM_CUSTOM: snprintf(buf, cap, "%s", strcmp(p->key, "search") == 0 ? "exact,patchmatch" : "0,2"); break;
  }
}

/* Reads spec lines key=value back into params through the table. */
static void read_back(const ts_param *t, void *params, char *text) {
  for (char *line = strtok(text, "\n"); line != NULL; line = strtok(NULL, "\n")) {
    char *eq = strchr(line, '=');
    assert_non_null(eq);
    *eq = '\0';
    if (ts_params_set(t, params, line, eq + 1) != 0) fail_msg("%s=%s does not read back", line, eq + 1);
  }
}

/* The parameters without a default (mrf's size, aerial's classes) given,
 * as every spec must give them. */
static void given_required(const ts_param *t, void *params) {
  for (const ts_param *p = t; p->key != NULL; p++) {
    if (p->def != NULL) continue;
    char v[128];
    other_value(p, v, sizeof(v));
    assert_int_equal(ts_params_set(t, params, p->key, v), 0);
  }
}

static void every_parameter_round_trips_through_the_spec(void **state) {
  (void)state;
  for (size_t e = 0; e < sizeof(kEngines) / sizeof(kEngines[0]); e++) {
    const ts_engine *engine = ts_engine_find(kEngines[e]);
    assert_non_null(engine);
    for (const ts_param *p = engine->params; p->key != NULL; p++) {
      if (p->flags & TS_PARAM_EMBEDDED) continue;
      static ts_engine_params a, b;
      engine->params_default(&a);
      engine->params_default(&b);
      given_required(engine->params, &a);
      char v[128], got[128], want[128], spec[4096];
      other_value(p, v, sizeof(v));
      assert_int_equal(ts_params_set(engine->params, &a, p->key, v), 0);
      assert_false(ts_param_is_default(p, &a));
      int n = ts_params_format(engine->params, &a, spec, sizeof(spec));
      assert_true(n > 0);
      char line[160];
      snprintf(line, sizeof(line), "%s=", p->key);
      if (strstr(spec, line) == NULL) fail_msg("%s: %s is not in the spec:\n%s", engine->name, p->key, spec);
      read_back(engine->params, &b, spec);
      ts_param_format(p, &a, want, sizeof(want));
      ts_param_format(p, &b, got, sizeof(got));
      if (strcmp(got, want) != 0) fail_msg("%s: %s=%s read back as %s", engine->name, p->key, want, got);
    }
  }
}

static void a_spec_value_out_of_range_is_refused(void **state) {
  (void)state;
  const ts_engine *mrf = ts_engine_find("mrf");
  static ts_engine_params a;
  mrf->params_default(&a);
  assert_int_equal(ts_params_set(mrf->params, &a, "refine", "21"), TS_EINVAL);
  assert_int_equal(ts_params_set(mrf->params, &a, "wb", "4"), TS_EINVAL);
  assert_int_equal(ts_params_set(mrf->params, &a, "coarse_weight", "0"), TS_EINVAL);
  assert_int_equal(ts_params_set(mrf->params, &a, "coarse_weight", "nan"), TS_EINVAL);
  assert_int_equal(ts_params_set(mrf->params, &a, "stop_level", "1"), TS_ENOENT); /* in-process only */
  assert_int_equal(ts_params_set(mrf->params, &a, "refine", "20"), 0);
  const ts_engine *aerial = ts_engine_find("aerial");
  aerial->params_default(&a);
  assert_int_equal(ts_params_set(aerial->params, &a, "classes", "100000"), TS_EINVAL);
}

static void range_problems_name_the_option_and_the_range(void **state) {
  (void)state;
  const ts_engine *mrf = ts_engine_find("mrf");
  static ts_engine_params a;
  mrf->params_default(&a);
  char err[TS_ERR_LEN];
  assert_int_equal(ts_param_parse(ts_param_find(mrf->params, "wn"), &a, "12", "--wn", err), 0);
  assert_int_equal(ts_param_parse(ts_param_find(mrf->params, "usage_weight"), &a, "101", "--usage-weight", err), 0);
  assert_int_equal(ts_param_parse(ts_param_find(mrf->params, "wb"), &a, "x", "--wb", err), TS_EINVAL);
  assert_string_equal(err, "--wb x: need a whole number");
  char msg[1024] = "";
  int n = 0;
  ts_params_check(mrf->params, &a, msg, sizeof(msg), &n);
  assert_int_equal(n, 2);
  assert_string_equal(msg, "--wn 12: need an odd number in 3..41\n--usage-weight 101: need 0..100");
}

static void help_lines_show_range_and_default(void **state) {
  (void)state;
  char *buf = NULL;
  size_t len = 0;
  FILE *f = open_memstream(&buf, &len);
  ts_params_help(f, ts_engine_find("segment")->params, NULL);
  fclose(f);
  assert_non_null(strstr(buf, "  --window N           window width (odd, 3..31; default 9)\n"));
  assert_non_null(strstr(buf, "  --rgb-search         compare the three colour channels instead of luminance\n"));
  assert_null(strstr(buf, "--pairs")); /* spec only: follows from the inputs */
  free(buf);
}

/* texsyn video's guide weights (video_guides.h): 0 turns a guide off, a
 * value between 0 and the floor is refused, --help says both. */
static void a_zero_off_range_takes_zero_and_its_range(void **state) {
  (void)state;
  ts_video_weights w;
  ts_params_default(ts_video_params, &w);
  assert_true(w.edge == 0.5 && w.position == 1 && w.temporal == 1 && w.mask == 1);
  char err[TS_ERR_LEN], msg[1024] = "";
  int n = 0;
  assert_int_equal(ts_param_parse(ts_param_find(ts_video_params, "edge_weight"), &w, "0", "--edge-weight", err), 0);
  assert_int_equal(ts_param_parse(ts_param_find(ts_video_params, "position_weight"), &w, "0.01", "--position-weight",
                                  err), 0);
  ts_params_check(ts_video_params, &w, msg, sizeof(msg), &n);
  assert_int_equal(n, 1);
  assert_string_equal(msg, "--position-weight 0.01: need 0: off, or 0.02..100");
  char *buf = NULL;
  size_t len = 0;
  FILE *f = open_memstream(&buf, &len);
  ts_params_help(f, ts_video_params, NULL);
  fclose(f);
  assert_non_null(strstr(buf, "  --edge-weight W      the edge guide's weight (0: off, or 0.01..100; default\n"));
  free(buf);
}

/* A command's own default of an engine parameter (texsyn video's budget)
 * is what --help shows; the other entries keep the table's. */
static void a_commands_default_replaces_the_one_shown(void **state) {
  (void)state;
  const ts_param *stylize = ts_engine_find("stylize")->params;
  char *buf = NULL;
  size_t len = 0;
  FILE *f = open_memstream(&buf, &len);
  ts_params_help(f, stylize, ts_video_defaults);
  fclose(f);
  assert_non_null(strstr(buf, "(0..1000000; default 0.1)"));
  assert_null(strstr(buf, "(0..1000000; default 1)"));
  assert_non_null(strstr(buf, "(odd, 3..15; default 5)")); /* --patch-size, untouched */
  free(buf);
  assert_non_null(ts_param_find(stylize, ts_video_defaults[0].key));
  assert_string_equal(ts_param_find(stylize, "budget")->def, "1"); /* stylize's own stays */
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(a_commands_default_replaces_the_one_shown),
    cmocka_unit_test(a_zero_off_range_takes_zero_and_its_range),
    cmocka_unit_test(every_parameter_round_trips_through_the_spec),
    cmocka_unit_test(a_spec_value_out_of_range_is_refused),
    cmocka_unit_test(range_problems_name_the_option_and_the_range),
    cmocka_unit_test(help_lines_show_range_and_default),
};

TS_TEST_MAIN(tests)
