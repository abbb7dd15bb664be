/* paramopt.c - see paramopt.h. */
#include "paramopt.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "suggest.h"
#include "video_guides.h"

static size_t count_options(const struct option *t) {
  size_t n = 0;
  while (t[n].name != NULL) n++;
  return n;
}

int ts_paramopt_build(const ts_engine *e, const struct option *own, struct option *out, size_t cap) {
  size_t n = count_options(own);
  if (n >= cap) return TS_ETOOBIG;
  memcpy(out, own, n * sizeof(*out));
  for (int i = 0; e->params[i].key != NULL; i++) {
    const ts_param *p = &e->params[i];
    if (p->flag == NULL) continue;
    if (n + 1 >= cap) return TS_ETOOBIG;
    out[n++] = (struct option){p->flag, p->type == TS_PARAM_FLAG ? no_argument : required_argument, 0,
                               TS_OPT_PARAM + i};
  }
  for (int k = 0; k < e->noutputs; k++) {
    if (e->outputs[k].flag == NULL) continue;
    if (n + 1 >= cap) return TS_ETOOBIG;
    out[n++] = (struct option){e->outputs[k].flag, required_argument, 0, TS_OPT_SIDE + k};
  }
  out[n] = (struct option){0, 0, 0, 0};
  return 0;
}

int ts_paramopt_take(ts_job_cmd *o, int c, const char *arg, char *err) {
  const ts_engine *e = o->spec.engine;
  int nparams = ts_param_count(e->params);
  if (c >= TS_OPT_PARAM && c < TS_OPT_PARAM + nparams) {
    const ts_param *p = &e->params[c - TS_OPT_PARAM];
    char what[64];
    snprintf(what, sizeof(what), "--%s", p->flag);
    if (p->type == TS_PARAM_FLAG) arg = p->flags & TS_PARAM_NEGATE ? "0" : "1";
    return ts_param_parse(p, &o->spec.params, arg, what, err);
  }
  if (c >= TS_OPT_SIDE && c < TS_OPT_SIDE + e->noutputs) {
    ts_output_set(&o->out, e->outputs[c - TS_OPT_SIDE].key, arg);
    return 0;
  }
  return TS_ENOENT;
}

static int take(ts_job_cmd *o, const ts_cmd_options *cmd, void *ctx, int c, int argc, char **argv, char *err) {
  int rc = cmd->option(ctx, c, optarg, argc, argv, err);
  if (rc == TS_ENOENT) rc = ts_paramopt_take(o, c, optarg, err);
  if (rc == TS_ENOENT) rc = ts_job_option(o, c, optarg, err);
  if (rc == TS_ENOENT) rc = ts_error(err, TS_EINVAL, "unknown option (see texsyn %s --help)", o->cmd);
  return rc;
}

int ts_paramopt_parse(ts_job_cmd *o, const ts_cmd_options *cmd, void *ctx, int argc, char **argv, char *err) {
  struct option longopts[TS_PARAMOPT_MAX];
  if (ts_paramopt_build(o->spec.engine, cmd->own, longopts, TS_PARAMOPT_MAX) != 0)
    return ts_error(err, TS_EINVAL, "internal: too many options");
  for (const ts_param_default *d = cmd->defaults; d != NULL && d->key != NULL; d++) {
    const ts_param *p = ts_param_find(o->spec.engine->params, d->key);
    if (p == NULL || ts_param_parse(p, &o->spec.params, d->value, d->key, err) != 0)
      return ts_error(err, TS_EINVAL, "internal: texsyn %s's default %s=%s", o->cmd, d->key, d->value);
  }
  optind = 1;
  opterr = 0;
  int c;
  while ((c = getopt_long(argc, argv, cmd->shortopts, longopts, NULL)) != -1) {
    if (c == TS_OPT_HELP || c == 'h') {
      cmd->usage(stdout, o->spec.engine);
      exit(0);
    }
    if (c == '?' || c == ':') return ts_arg_unknown(o->cmd, argv[optind - 1], longopts, err);
    int rc = take(o, cmd, ctx, c, argc, argv, err);
    if (rc != 0) return rc;
  }
  if (optind < argc) return ts_error(err, TS_EINVAL, "unexpected argument '%s'", argv[optind]);
  return 0;
}

int ts_paramopt_check(const ts_job_cmd *o, char *err) {
  if (o->server == NULL) return 0;
  for (const ts_param *p = o->spec.engine->params; p->key != NULL; p++)
    if ((p->flags & TS_PARAM_EMBEDDED) && !ts_param_is_default(p, &o->spec.params))
      return ts_error(err, TS_EINVAL, "--%s runs in-process only (add --embedded)", p->flag);
  return 0;
}

void ts_paramopt_help(FILE *f, const ts_engine *e) {
  ts_params_help(f, e->params, NULL);
  for (int k = 0; k < e->noutputs; k++) {
    if (e->outputs[k].flag == NULL) continue;
    char option[64];
    snprintf(option, sizeof(option), "--%s F", e->outputs[k].flag);
    ts_help_line(f, option, e->outputs[k].help);
  }
}

double ts_paramopt_number(const ts_job_cmd *o, const char *key) {
  const ts_param *p = ts_param_find(o->spec.engine->params, key);
  return p != NULL ? ts_param_number(p, &o->spec.params) : 0;
}

/* One table, under its heading ("engine mrf", "command video"): spec key,
 * option, default, range, help; then the command's own defaults of its
 * engine's parameters. */
static void print_table(const char *kind, const char *name, const ts_param *params, const ts_engine *engine,
                        const ts_param_default *own) {
  printf("%s %s\n", kind, name);
  for (const ts_param *p = params; p->key != NULL; p++) {
    char option[64] = "-", def[128] = "-";
    if (p->flag != NULL) snprintf(option, sizeof(option), "--%s", p->flag);
    if (p->def != NULL) snprintf(def, sizeof(def), "%s", p->def);
    printf("  %-18s %-20s %-10s %s%s\n", p->key, option, def, p->help,
           p->flags & TS_PARAM_EMBEDDED ? " [in-process only, not a spec key]" : "");
  }
  for (; own != NULL && own->key != NULL; own++) {
    const ts_param *p = ts_param_find(engine->params, own->key);
    char option[64];
    snprintf(option, sizeof(option), "--%s", p->flag);
    printf("  %-18s %-20s %-10s %s's, with this default here\n", own->key, option, own->value, engine->name);
  }
}

/* Commands with parameters of their own, beside their engine's: texsyn
 * video's guide weights and its defaults (video_guides.h). */
static const struct {
  const char *name;
  const ts_param *params;
  const char *engine; /* whose parameters the defaults are */
  const ts_param_default *defaults;
} command_tables[] = {{"video", ts_video_params, "stylize", ts_video_defaults}};
#define NCOMMAND_TABLES (sizeof(command_tables) / sizeof(command_tables[0]))

int ts_cmd_params(int argc, char **argv) {
  if (argc > 2 || (argc == 2 && argv[1][0] == '-')) {
    printf("usage: texsyn params [ENGINE|COMMAND]\n"
           "Lists each engine's parameters (or ENGINE's), then those of the commands that\n"
           "have their own (or COMMAND's: video): the job spec key, the command-line option\n"
           "(- for a key set from the inputs), the default and what it does.\n");
    return argc == 2 && (strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0) ? 0 : 2;
  }
  const ts_engine *e;
  for (size_t c = 0; argc == 2 && c < NCOMMAND_TABLES; c++)
    if (strcmp(argv[1], command_tables[c].name) == 0) {
      print_table("command", command_tables[c].name, command_tables[c].params,
                  ts_engine_find(command_tables[c].engine), command_tables[c].defaults);
      return 0;
    }
  if (argc == 2 && (e = ts_engine_find(argv[1])) == NULL) {
    fprintf(stderr, "texsyn params: no engine or command '%s' (texsyn params lists them)\n", argv[1]);
    return 2;
  }
  if (argc == 2) print_table("engine", e->name, e->params, NULL, NULL);
  for (int i = 0; argc == 1 && (e = ts_engine_at(i)) != NULL; i++) print_table("engine", e->name, e->params, NULL, NULL);
  for (size_t c = 0; argc == 1 && c < NCOMMAND_TABLES; c++)
    print_table("command", command_tables[c].name, command_tables[c].params,
                  ts_engine_find(command_tables[c].engine), command_tables[c].defaults);
  return 0;
}
