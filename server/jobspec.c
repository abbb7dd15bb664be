/* jobspec.c - see jobspec.h. */
#include "jobspec.h"

#include <stdio.h>
#include <string.h>

#include "error.h"
#include "util.h"

void ts_jobspec_default(ts_jobspec *s) {
  memset(s, 0, sizeof(*s));
  ts_mrf_params_default(&s->p);
  snprintf(s->output, sizeof(s->output), "png");
}

const char *ts_path_ext(const char *path) {
  const char *slash = strrchr(path, '/');
  const char *dot = strrchr(path, '.');
  return dot != NULL && (slash == NULL || dot > slash) ? dot + 1 : "";
}

int ts_jobspec_format(const ts_jobspec *s, char *buf, size_t cap) {
  const ts_mrf_params *p = &s->p;
  int n = snprintf(buf, cap,
                   "size=%dx%d\nlevels=%d\nwn=%d\nwb=%d\nparity=%d\nusage_weight=%.17g\n"
                   "coarse_weight=%.17g\nrefine=%d\nseed=%llu\nrgb_search=%d\nmax_pixels=%llu\n"
                   "output=%s\ncopy_map=%s\ncopy_map_raw=%d\nusage_map=%s\nreport=%d\n",
                   p->width, p->height, p->levels, p->wn, p->wb, p->parity, p->usage_weight,
                   p->coarse_weight, p->refine, (unsigned long long)p->seed, p->rgb_search,
                   (unsigned long long)p->max_pixels, s->output, s->copy_map, s->copy_map_raw,
                   s->usage_map, s->report);
  return n < 0 || (size_t)n >= cap ? TS_ETOOBIG : n;
}

/* An extension: letters and digits only, so a spec can never steer a file
 * name out of the job's directory. */
static int parse_ext(const char *v, char *out) {
  size_t n = strlen(v);
  if (n >= TS_EXT_LEN) return TS_EINVAL;
  for (size_t i = 0; i < n; i++)
    if (!((v[i] >= 'a' && v[i] <= 'z') || (v[i] >= 'A' && v[i] <= 'Z') || (v[i] >= '0' && v[i] <= '9'))) return TS_EINVAL;
  memcpy(out, v, n + 1);
  return 0;
}

int ts_ext_valid(const char *ext) {
  char tmp[TS_EXT_LEN];
  return ext[0] != '\0' && parse_ext(ext, tmp) == 0;
}

/* 0, TS_EINVAL for a bad value, TS_ENOENT for an unknown key. */
static int set_key(ts_jobspec *s, const char *k, const char *v) {
  ts_mrf_params *p = &s->p;
  if (strcmp(k, "size") == 0) return ts_parse_size(v, TS_OUTPUT_SIDE_MAX, &p->width, &p->height) != 0 ? TS_EINVAL : 0;
  if (strcmp(k, "levels") == 0) return ts_parse_int(v, -1000, 1000, &p->levels);
  if (strcmp(k, "wn") == 0) return ts_parse_int(v, -1000, 1000, &p->wn);
  if (strcmp(k, "wb") == 0) return ts_parse_int(v, -1000, 1000, &p->wb);
  if (strcmp(k, "parity") == 0) return ts_parse_int(v, 0, 1, &p->parity);
  if (strcmp(k, "usage_weight") == 0) return ts_parse_double(v, &p->usage_weight);
  if (strcmp(k, "coarse_weight") == 0) return ts_parse_double(v, &p->coarse_weight);
  if (strcmp(k, "refine") == 0) return ts_parse_int(v, -1000, 1000, &p->refine);
  if (strcmp(k, "seed") == 0) return ts_parse_u64(v, &p->seed);
  if (strcmp(k, "rgb_search") == 0) return ts_parse_int(v, 0, 1, &p->rgb_search);
  if (strcmp(k, "max_pixels") == 0) return ts_parse_u64(v, &p->max_pixels);
  if (strcmp(k, "output") == 0) return parse_ext(v, s->output);
  if (strcmp(k, "copy_map") == 0) return parse_ext(v, s->copy_map);
  if (strcmp(k, "usage_map") == 0) return parse_ext(v, s->usage_map);
  if (strcmp(k, "copy_map_raw") == 0) return ts_parse_int(v, 0, 1, &s->copy_map_raw);
  if (strcmp(k, "report") == 0) return ts_parse_int(v, 0, 1, &s->report);
  return TS_ENOENT;
}

int ts_jobspec_parse(const char *text, size_t len, ts_jobspec *s, char *err) {
  ts_jobspec_default(s);
  size_t off = 0;
  int line = 0;
  while (off < len) {
    line++;
    const char *nl = memchr(text + off, '\n', len - off);
    size_t n = nl ? (size_t)(nl - (text + off)) : len - off;
    char buf[256];
    if (n >= sizeof(buf)) return ts_error(err, TS_EINVAL, "job spec line %d is too long", line);
    memcpy(buf, text + off, n);
    buf[n] = '\0';
    off += n + 1;
    if (n == 0) continue;
    if (memchr(buf, '\0', n) != NULL) return ts_error(err, TS_EINVAL, "job spec line %d holds a NUL byte", line);
    char *eq = strchr(buf, '=');
    if (eq == NULL) return ts_error(err, TS_EINVAL, "job spec line %d: expected key=value", line);
    *eq = '\0';
    int rc = set_key(s, buf, eq + 1);
    if (rc == TS_ENOENT) return ts_error(err, TS_EINVAL, "job spec line %d: unknown key '%s'", line, buf);
    if (rc != 0) return ts_error(err, TS_EINVAL, "job spec line %d: bad value '%s' for %s", line, eq + 1, buf);
  }
  if (s->output[0] == '\0') return ts_error(err, TS_EINVAL, "job spec: output format is required");
  /* Without it the spec would format as size=0x0, which no parse takes
   * back: a spooled job would be lost on a restart. */
  if (s->p.width == 0) return ts_error(err, TS_EINVAL, "job spec: size=WxH is required");
  return 0;
}
