/* frames.c - see frames.h. */
#include "frames.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "error.h"
#include "util.h"

#define FRAME_PATH 4096

int ts_frames_parse(const char *s, ts_frames *f, char *err) {
  const char *dots = strstr(s, "..");
  char a[32];
  size_t n = dots != NULL ? (size_t)(dots - s) : 0;
  int ok = dots != NULL && n > 0 && n < sizeof(a);
  if (ok) {
    memcpy(a, s, n);
    a[n] = '\0';
    long first, last;
    ok = ts_parse_long(a, 0, TS_FRAME_LAST, &first) == 0 && ts_parse_long(dots + 2, 0, TS_FRAME_LAST, &last) == 0;
    if (ok && (last < first || last - first >= TS_FRAMES_MAX))
      return ts_error(err, TS_EINVAL, "--frames %s: need A <= B and at most %d frames", s, TS_FRAMES_MAX);
    f->first = first;
    f->last = last;
  }
  return ok ? 0 : ts_error(err, TS_EINVAL, "--frames %s: expected A..B, frame numbers 0..%d (e.g. 1..10)", s,
                           TS_FRAME_LAST);
}

/* The conversion at s (just after a '%'): its width and zero flag, and
 * its length; 0 when it is no frame-number conversion. */
static size_t conversion(const char *s, int *zero, int *width) {
  size_t i = 0;
  *zero = s[0] == '0';
  i += (size_t)*zero;
  *width = 0;
  while (s[i] >= '0' && s[i] <= '9' && *width < 100) *width = *width * 10 + (s[i++] - '0');
  return s[i] == 'd' && *width <= 9 ? i + 1 : 0;
}

int ts_frame_pattern(const char *path, char *err) {
  int n = 0, zero, width;
  for (const char *p = strchr(path, '%'); p != NULL; p = strchr(p, '%')) {
    if (p[1] == '%') {
      p += 2;
      continue;
    }
    size_t len = conversion(p + 1, &zero, &width);
    if (len == 0)
      return ts_error(err, TS_EINVAL, "%s: a '%%' in a --frames path starts the frame number (%%d, %%04d) or a "
                      "per cent sign (%%%%)", path);
    n++;
    p += 1 + len;
  }
  return n;
}

int ts_frame_path(const char *pattern, long frame, char *out, size_t cap) {
  size_t o = 0;
  for (const char *p = pattern; *p != '\0';) {
    char piece[32];
    int zero, width;
    size_t len = 1;
    if (p[0] == '%' && p[1] == '%') {
      snprintf(piece, sizeof(piece), "%%");
      len = 2;
    } else if (p[0] == '%' && (len = conversion(p + 1, &zero, &width)) > 0) {
      snprintf(piece, sizeof(piece), zero ? "%0*ld" : "%*ld", width, frame);
      len++;
    } else {
      piece[0] = *p;
      piece[1] = '\0';
      len = 1;
    }
    size_t k = strlen(piece);
    if (o + k >= cap) return TS_ETOOBIG;
    memcpy(out + o, piece, k);
    o += k;
    p += len;
  }
  out[o] = '\0';
  return 0;
}

/* ---- one frame's job -------------------------------------------------- */

typedef struct {
  ts_job_cmd job; /* the sequence's, with this frame's paths */
  char in[TS_ENGINE_MAX_INPUTS][FRAME_PATH];
  char out[TS_ENGINE_MAX_OUTPUTS * 2][FRAME_PATH];
} frame_job;

/* The job of frame f: every path with the frame number put in. */
static int frame_expand(const ts_job_cmd *o, int ninputs, long f, frame_job *fj, char *err) {
  fj->job = *o;
  for (int k = 0; k < ninputs; k++) {
    if (ts_frame_path(o->in[k], f, fj->in[k], FRAME_PATH) != 0)
      return ts_error(err, TS_EINVAL, "%s: path too long", o->in[k]);
    fj->job.in[k] = fj->in[k];
  }
  for (int i = 0; i < o->out.n; i++) {
    if (ts_frame_path(o->out.path[i], f, fj->out[i], FRAME_PATH) != 0)
      return ts_error(err, TS_EINVAL, "%s: path too long", o->out.path[i]);
    fj->job.out.path[i] = fj->out[i];
  }
  return 0;
}

/* The patterns: one in every output, none in a fixed input, and some
 * input that varies (else every frame is the same job). */
static int check_patterns(const ts_job_cmd *o, int ninputs, const char *const *fixed, uint8_t *varies, char *err) {
  int any = 0;
  for (int i = 0; i < o->out.n; i++) {
    int n = ts_frame_pattern(o->out.path[i], err);
    if (n < 0) return n;
    if (n == 0)
      return ts_error(err, TS_EINVAL, "%s: an output of --frames needs the frame number in its name (%%04d: "
                      "out_%%04d.png), or every frame would overwrite it", o->out.path[i]);
  }
  for (int k = 0; k < ninputs; k++) {
    int n = ts_frame_pattern(o->in[k], err);
    if (n < 0) return n;
    if (n > 0 && fixed[k] != NULL)
      return ts_error(err, TS_EINVAL, "%s: %s is the same for every frame; only the target guides take a frame "
                      "number", o->in[k], fixed[k]);
    varies[k] = n > 0;
    any |= n > 0;
  }
  if (!any)
    return ts_error(err, TS_EINVAL, "--frames: no input has a frame number in its name (%%04d: "
                    "target_%%04d.png), so every frame would be the same");
  return 0;
}

/* Every frame's inputs readable and outputs writable, before any work. */
static int check_frames(const ts_job_cmd *o, const ts_frames *fr, int ninputs, const uint8_t *varies,
                        frame_job *fj, char *err) {
  for (long f = fr->first; f <= fr->last; f++) {
    int rc = frame_expand(o, ninputs, f, fj, err);
    for (int k = 0; rc == 0 && k < ninputs; k++)
      if ((varies[k] || f == fr->first) && access(fj->in[k], R_OK) != 0)
        rc = ts_error(err, TS_EIO, "frame %ld: cannot read %s: %m (nothing was run)", f, fj->in[k]);
    if (rc == 0 && !o->detach) rc = ts_job_check_outputs(&fj->job, err);
    if (rc != 0) return rc;
  }
  return 0;
}

/* ---- the sequence ----------------------------------------------------- */

typedef struct {
  const ts_job_cmd *o;
  const ts_frames *fr;
  int ninputs;
  uint8_t varies[TS_ENGINE_MAX_INPUTS];
  ts_image fixed_in[TS_ENGINE_MAX_INPUTS]; /* the inputs that do not vary, read once */
  frame_job *fj;
} sequence;

/* Frame f's inputs read (the varying ones into in[], the others shared)
 * and checked by the engine: 0, TS_EINVAL (reported) or another error. */
static int frame_inputs(sequence *s, long f, ts_image *in, const ts_image **inp, char *err) {
  ts_image_limits limits = {s->o->max_pixels, NULL};
  int rc = frame_expand(s->o, s->ninputs, f, s->fj, err);
  for (int k = 0; rc == 0 && k < s->ninputs; k++) {
    if (s->varies[k]) rc = ts_image_read(s->fj->in[k], &in[k], &limits, err);
    inp[k] = s->varies[k] ? &in[k] : &s->fixed_in[k];
  }
  char msg[4096];
  if (rc == 0 && s->o->spec.engine->check(&s->o->spec.params, inp, msg, sizeof(msg)) != 0)
    rc = ts_error(err, TS_EINVAL, "frame %ld: invalid inputs:\n%s", f, msg);
  return rc;
}

static void frame_inputs_free(sequence *s, ts_image *in) {
  for (int k = 0; k < s->ninputs; k++)
    if (s->varies[k]) ts_image_free(&in[k]);
}

static int run_embedded(sequence *s, char *err) {
  ts_search *search = NULL;
  int rc = ts_search_local_create(&search, s->o->threads, NULL, err);
  for (long f = s->fr->first; rc == 0 && f <= s->fr->last; f++) {
    ts_image in[TS_ENGINE_MAX_INPUTS] = {0};
    const ts_image *inp[TS_ENGINE_MAX_INPUTS];
    rc = frame_inputs(s, f, in, inp, err);
    if (rc == 0) rc = ts_job_embedded(&s->fj->job, inp, search, err);
    frame_inputs_free(s, in);
  }
  ts_search_destroy(search);
  return rc;
}

/* Puts "frame F: " before the message (its end cut if need be). */
static void frame_error(long f, char *err) {
  char head[32];
  int n = snprintf(head, sizeof(head), "frame %ld: ", f);
  size_t keep = strnlen(err, TS_ERR_LEN - 1 - (size_t)n);
  memmove(err + n, err, keep);
  memcpy(err, head, (size_t)n);
  err[(size_t)n + keep] = '\0';
}

/* Checks and submits every frame, then follows each to its end in order
 * and fetches it. */
static int run_remote(sequence *s, char *err) {
  const ts_job_cmd *o = s->o;
  long n = s->fr->last - s->fr->first + 1;
  uint64_t *ids = calloc((size_t)n, sizeof(*ids));
  ts_conn c;
  int rc = ids != NULL ? ts_job_open(&c, o, err) : ts_error(err, TS_ENOMEM, "out of memory");
  int connected = ids != NULL && rc == 0;
  for (long i = 0; rc == 0 && i < n; i++) {
    ts_image in[TS_ENGINE_MAX_INPUTS] = {0};
    const ts_image *inp[TS_ENGINE_MAX_INPUTS];
    rc = frame_inputs(s, s->fr->first + i, in, inp, err);
    frame_inputs_free(s, in);
    if (rc == 0) rc = ts_job_submit(&c, &s->fj->job, &ids[i], err);
    if (rc == 0 && o->detach) printf("%llu\n", (unsigned long long)ids[i]);
  }
  for (long i = 0; rc == 0 && !o->detach && i < n; i++) {
    long f = s->fr->first + i;
    rc = frame_expand(o, s->ninputs, f, s->fj, err);
    if (rc == 0 && (rc = ts_job_finish(&c, &s->fj->job, ids[i], err)) != 0) frame_error(f, err);
  }
  if (connected) ts_conn_close(&c);
  free(ids);
  return rc;
}

int ts_job_run_frames(const ts_job_cmd *o, const ts_frames *fr, const char *const *fixed) {
  char err[TS_ERR_LEN] = "";
  sequence *s = calloc(1, sizeof(*s));
  frame_job *fj = calloc(1, sizeof(*fj));
  if (s == NULL || fj == NULL) {
    free(s);
    free(fj);
    fprintf(stderr, "texsyn %s: out of memory\n", o->cmd);
    return 1;
  }
  ts_engine_inputs names;
  o->spec.engine->inputs(&o->spec.params, &names);
  *s = (sequence){.o = o, .fr = fr, .ninputs = names.n, .fj = fj};
  int rc = check_patterns(o, names.n, fixed, s->varies, err);
  if (rc == 0) rc = check_frames(o, fr, names.n, s->varies, fj, err);
  ts_image_limits limits = {o->max_pixels, NULL};
  for (int k = 0; rc == 0 && k < names.n; k++)
    if (!s->varies[k]) rc = ts_image_read(o->in[k], &s->fixed_in[k], &limits, err);
  if (rc == 0) rc = o->server == NULL ? run_embedded(s, err) : run_remote(s, err);
  if (rc != 0) fprintf(stderr, "texsyn %s: %s\n", o->cmd, err);
  for (int k = 0; k < names.n; k++) ts_image_free(&s->fixed_in[k]);
  free(fj);
  free(s);
  return rc == 0 ? 0 : rc == TS_EINVAL ? 2 : 1;
}
