/* video_chain.c - see video_chain.h. */
#include "video_chain.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "error.h"
#include "flow.h"
#include "image.h"
#include "util.h"
#include "video_flow.h"
#include "video_guides.h"
#include "video_mask.h"

/* ---- the work directory's files ---------------------------------------- */

void ts_video_chain_file(const char *dir, long key, long t, const char *what, char *out, size_t cap) {
  snprintf(out, cap, "%s/from_%04ld_%04ld_%s", dir, key, t, what);
}

/* The key's 8-bit painting ("" what) or source guide ("edge", and
 * "complement": 255 - the painting, ts_guide_temporal_pair's). */
static void key_file(const char *dir, long key, const char *what, char *out, size_t cap) {
  snprintf(out, cap, "%s/key_%04ld%s%s.png", dir, key, what[0] ? "_" : "", what);
}

static void identity_file(const char *dir, const char *axis, char *out, size_t cap) {
  snprintf(out, cap, "%s/position_%s.png", dir, axis);
}

/* Writes w x h pixels of c interleaved 8-bit channels as a PNG. */
static int write_u8(const char *path, const uint8_t *px, int w, int h, int c, char *err) {
  ts_image img = {w, h, c, TS_PIX_U8, (void *)px, NULL};
  return ts_image_write(path, &img, NULL, err);
}

int ts_video_write_floats(const char *path, const float *f, size_t n, char *err) {
  return ts_file_write(path, f, n * sizeof(float), err);
}

int ts_video_read_floats(const char *path, float *f, size_t n, char *err) {
  uint8_t *buf = NULL;
  size_t len = 0;
  int rc = ts_file_read(path, n * sizeof(float) + 1, &buf, &len, err);
  if (rc == 0 && len != n * sizeof(float))
    rc = ts_error(err, TS_EFORMAT, "%s holds %zu bytes, not the %zu of %zu floats", path, len, n * sizeof(float), n);
  if (rc == 0) memcpy(f, buf, len);
  free(buf);
  return rc;
}

int ts_video_read8(const ts_video *v, const char *path, uint8_t *px, char *err) {
  ts_image img = {0};
  ts_image_limits limits = {v->job.max_pixels, NULL};
  int rc = ts_image_read(path, &img, &limits, err);
  uint8_t *plane = rc == 0 ? malloc((size_t)v->w * v->h) : NULL;
  if (rc == 0 && plane == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory for %s", path);
  if (rc == 0 && (img.width != v->w || img.height != v->h || img.channels != v->channels))
    rc = ts_error(err, TS_EFORMAT, "%s is %dx%d with %d channels, expected %dx%d with %d", path, img.width,
                  img.height, img.channels, v->w, v->h, v->channels);
  for (int c = 0; rc == 0 && c < v->channels; c++) {
    ts_image_channel8(&img, c, plane);
    for (size_t i = 0; i < (size_t)v->w * v->h; i++) px[i * v->channels + c] = plane[i];
  }
  free(plane);
  ts_image_free(&img);
  return rc;
}

/* The luminance of input frame t. */
static int read_luma(const ts_video *v, long t, uint8_t *luma, char *err) {
  char path[TS_VIDEO_PATH];
  ts_frame_path(v->input, t, path, sizeof(path)); /* fits: checked */
  ts_image img = {0};
  ts_image_limits limits = {v->job.max_pixels, NULL};
  int rc = ts_image_read(path, &img, &limits, err);
  if (rc == 0) ts_image_luma8(&img, luma);
  ts_image_free(&img);
  return rc;
}

/* The edge guide of input frame t, written to path. */
static int write_edges(const ts_video *v, long t, const char *path, char *err) {
  size_t n = (size_t)v->w * v->h;
  uint8_t *luma = malloc(n), *edges = malloc(n);
  int rc = luma != NULL && edges != NULL ? read_luma(v, t, luma, err) : ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0 && ts_guide_edges(luma, v->w, v->h, edges) != 0) rc = ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) rc = write_u8(path, edges, v->w, v->h, 1, err);
  free(luma);
  free(edges);
  return rc;
}

/* A position guide as its two planes, x and y, written beside each other. */
static int write_position(const float *pos, int w, int h, const char *px_path, const char *py_path, char *err) {
  uint8_t *px = malloc((size_t)w * h), *py = malloc((size_t)w * h);
  int rc = px != NULL && py != NULL ? 0 : ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) ts_guide_position_planes(pos, w, h, px, py);
  if (rc == 0) rc = write_u8(px_path, px, w, h, 1, err);
  if (rc == 0) rc = write_u8(py_path, py, w, h, 1, err);
  free(px);
  free(py);
  return rc;
}

/* ---- the guides' order and weights ------------------------------------- */

/* The guide pairs of frame t of the chain from key (t == key: the key's
 * own frame, target = source) into in[], in the engine's order; the count. */
static int job_paths(const ts_video *v, const char *dir, long key, long t, char in[][TS_VIDEO_PATH]) {
  int own = t == key, g = 0;
  key_file(dir, key, "", in[TS_STYLIT_IN_STYLE], TS_VIDEO_PATH);
  ts_frame_path(v->input, key, in[ts_stylit_in_src(g)], TS_VIDEO_PATH);
  ts_frame_path(v->input, t, in[ts_stylit_in_tgt(g++)], TS_VIDEO_PATH);
  if (v->wt.edge > 0) {
    key_file(dir, key, "edge", in[ts_stylit_in_src(g)], TS_VIDEO_PATH);
    ts_video_chain_file(dir, key, t, "edge.png", in[ts_stylit_in_tgt(g++)], TS_VIDEO_PATH);
  }
  static const char *const axes[2] = {"x", "y"};
  for (int a = 0; a < 2 && v->wt.position > 0; a++) {
    char what[32];
    snprintf(what, sizeof(what), "position_%s.png", axes[a]);
    identity_file(dir, axes[a], in[ts_stylit_in_src(g)], TS_VIDEO_PATH);
    ts_video_chain_file(dir, key, t, what, in[ts_stylit_in_tgt(g++)], TS_VIDEO_PATH);
  }
  if (v->wt.temporal > 0) { /* a pair: ts_guide_temporal_pair */
    key_file(dir, key, "", in[ts_stylit_in_src(g)], TS_VIDEO_PATH);
    ts_video_chain_file(dir, key, t, "temporal.png", in[ts_stylit_in_tgt(g++)], TS_VIDEO_PATH);
    key_file(dir, key, "complement", in[ts_stylit_in_src(g)], TS_VIDEO_PATH);
    ts_video_chain_file(dir, key, t, "temporal_complement.png", in[ts_stylit_in_tgt(g++)], TS_VIDEO_PATH);
  }
  if (v->mask != NULL && v->wt.mask > 0) {
    ts_video_mask_file(dir, key, in[ts_stylit_in_src(g)], TS_VIDEO_PATH);
    ts_video_mask_file(dir, t, in[ts_stylit_in_tgt(g++)], TS_VIDEO_PATH);
  }
  for (int p = 0; p < v->npass; p++) {
    ts_frame_path(v->pass[p], key, in[ts_stylit_in_src(g)], TS_VIDEO_PATH);
    ts_frame_path(v->pass[p], t, in[ts_stylit_in_tgt(g++)], TS_VIDEO_PATH);
  }
  if (own) /* the key's own frame: its made targets are its sources */
    for (int k = 0; k < g; k++) memcpy(in[ts_stylit_in_tgt(k)], in[ts_stylit_in_src(k)], TS_VIDEO_PATH);
  return g;
}

int ts_video_weigh(ts_video *v, char *err) {
  double w[TS_STYLIT_MAX_GUIDES];
  int g = 0;
  w[g++] = v->input_weight;
  if (v->wt.edge > 0) w[g++] = v->wt.edge;
  for (int a = 0; a < 2 && v->wt.position > 0; a++) w[g++] = v->wt.position / 2; /* x and y */
  for (int a = 0; a < 2 && v->wt.temporal > 0; a++) w[g++] = v->wt.temporal / 2; /* it and its complement */
  if (v->mask != NULL && v->wt.mask > 0) w[g++] = v->wt.mask;
  for (int p = 0; p < v->npass; p++) w[g++] = v->pass_weight[p];
  char key[32], value[32];
  snprintf(value, sizeof(value), "%d", g);
  int rc = ts_job_set_key(&v->job, "guides", value, "the guides", err);
  for (int k = 0; rc == 0 && k < g; k++) {
    snprintf(key, sizeof(key), "weight_%d", k);
    snprintf(value, sizeof(value), "%.17g", w[k]);
    rc = ts_job_set_key(&v->job, key, value, "a guide's weight", err);
  }
  return rc;
}

/* ---- preparing the keys ------------------------------------------------ */

/* Key k's 8-bit painting and its edge guide, in dir. */
static int prepare_key(const ts_video *v, const char *dir, int k, char *err) {
  char path[TS_VIDEO_PATH];
  uint8_t *px = malloc((size_t)v->w * v->h * v->channels);
  int rc = px != NULL ? ts_video_read8(v, v->key[k].image, px, err) : ts_error(err, TS_ENOMEM, "out of memory");
  key_file(dir, v->key[k].frame, "", path, sizeof(path));
  if (rc == 0) rc = write_u8(path, px, v->w, v->h, v->channels, err);
  ts_video_chain_file(dir, v->key[k].frame, v->key[k].frame, "out.png", path, sizeof(path));
  if (rc == 0) rc = write_u8(path, px, v->w, v->h, v->channels, err); /* the key's own frame */
  key_file(dir, v->key[k].frame, "complement", path, sizeof(path));
  ts_guide_complement(px, (size_t)v->w * (size_t)v->h * (size_t)v->channels, px);
  if (rc == 0 && v->wt.temporal > 0) rc = write_u8(path, px, v->w, v->h, v->channels, err);
  free(px);
  key_file(dir, v->key[k].frame, "edge", path, sizeof(path));
  if (rc == 0 && v->wt.edge > 0) rc = write_edges(v, v->key[k].frame, path, err);
  return rc;
}

/* Reads a job's n inputs into in[] and asks the engine about them: 0, or
 * TS_EINVAL with the engine's problems (the images read either way, for
 * free_inputs). */
static int load_job(const ts_job_cmd *job, int n, ts_image *in, const ts_image **inp, char *err) {
  ts_image_limits limits = {job->max_pixels, NULL};
  int rc = 0;
  for (int k = 0; k < n; k++) {
    if (rc == 0) rc = ts_image_read(job->in[k], &in[k], &limits, err);
    inp[k] = &in[k];
  }
  char msg[4096];
  if (rc == 0 && job->spec.engine->check(&job->spec.params, inp, msg, sizeof(msg)) != 0)
    rc = ts_error(err, TS_EINVAL, "the stylize jobs would fail (nothing was stylized):\n%s", msg);
  return rc;
}

static void free_inputs(ts_image *in, int n) {
  for (int k = 0; k < n; k++) ts_image_free(&in[k]);
}

/* ---- a chain ----------------------------------------------------------- */

typedef struct {
  long key, frame, last; /* frame: the last one stylized */
  int dir;               /* +1 forward, -1 backward */
  uint8_t *painting;     /* the key's, 8-bit, interleaved */
  uint8_t *luma;         /* input frame `frame` */
  float *pos;            /* the position guide at `frame` */
  float *sty;            /* the stylized frame `frame`, 8-bit values */
  float *acc;            /* the error piled up along the chain to `frame` */
  float *flow;           /* the flow from the frame under way to `frame` */
  uint64_t id;           /* the running job on a coordinator */
  ts_job_cmd job;
  char in[TS_ENGINE_MAX_INPUTS][TS_VIDEO_PATH];
  char out[TS_VIDEO_PATH], report[TS_VIDEO_PATH], error[TS_VIDEO_PATH], name[64];
} chain;

/* One step's scratch, shared by the chains (one step is made at a time). */
typedef struct {
  uint8_t *luma, *occluded, *px, *px2;
  float *back, *fwd, *pos, *warped, *scratch;
} step_buf;

static void chain_free(chain *c) {
  free(c->painting);
  free(c->luma);
  free(c->pos);
  free(c->sty);
  free(c->acc);
  free(c->flow);
}

static int chain_init(const ts_video *v, const char *dir, long key, long last, chain *c, char *err) {
  size_t n = (size_t)v->w * v->h;
  *c = (chain){.key = key, .frame = key, .last = last, .dir = last > key ? 1 : -1};
  c->painting = malloc(n * v->channels);
  c->luma = malloc(n);
  c->pos = malloc(sizeof(float) * 2 * n);
  c->sty = malloc(sizeof(float) * n * v->channels);
  c->acc = calloc(n, sizeof(float)); /* the key's own frame: no error */
  c->flow = malloc(sizeof(float) * 2 * n);
  if (!c->painting || !c->luma || !c->pos || !c->sty || !c->acc || !c->flow)
    return ts_error(err, TS_ENOMEM, "out of memory");
  char path[TS_VIDEO_PATH];
  key_file(dir, key, "", path, sizeof(path));
  int rc = ts_video_read8(v, path, c->painting, err);
  if (rc == 0) rc = read_luma(v, key, c->luma, err);
  for (size_t i = 0; i < n * v->channels; i++) c->sty[i] = c->painting[i];
  ts_guide_position_key(v->w, v->h, c->pos);
  return rc;
}

static int step_buf_alloc(step_buf *b, const ts_video *v, char *err) {
  size_t n = (size_t)v->w * v->h;
  b->luma = malloc(n);
  b->occluded = malloc(n);
  b->px = malloc(n * v->channels);
  b->px2 = malloc(n * v->channels);
  b->back = malloc(sizeof(float) * 2 * n);
  b->fwd = malloc(sizeof(float) * 2 * n);
  b->pos = malloc(sizeof(float) * 2 * n);
  b->warped = malloc(sizeof(float) * n * v->channels);
  b->scratch = malloc(sizeof(float) * n);
  return b->luma && b->occluded && b->px && b->px2 && b->back && b->fwd && b->pos && b->warped && b->scratch
             ? 0
             : ts_error(err, TS_ENOMEM, "out of memory for the flows of %dx%d frames", v->w, v->h);
}

static void step_buf_free(step_buf *b) {
  free(b->luma);
  free(b->occluded);
  free(b->px);
  free(b->px2);
  free(b->back);
  free(b->fwd);
  free(b->pos);
  free(b->warped);
  free(b->scratch);
}

/* The temporal guide pair of frame t: the chain's last frame warped onto
 * t, and its complement, both 0 where t's pixel is occluded
 * (ts_guide_temporal_pair: weighted out there). */
static void temporal_guide(const ts_video *v, const chain *c, step_buf *b) {
  ts_flow_warp(c->sty, v->w, v->h, v->channels, b->back, b->warped);
  ts_guide_temporal_pair(b->warped, b->occluded, (size_t)v->w * (size_t)v->h, v->channels, b->px, b->px2);
}

/* The made guides of the chain's next frame t, written to dir; b->luma
 * and b->pos hold t's luminance and position guide. */
static int make_guides(const ts_video *v, const char *dir, chain *c, long t, step_buf *b, char *err) {
  int rc = read_luma(v, t, b->luma, err);
  if (rc == 0) rc = ts_video_flows(v, c->frame, t, c->luma, b->luma, b->back, b->fwd, b->scratch, err);
  if (rc != 0) return rc;
  memcpy(c->flow, b->back, sizeof(float) * 2 * (size_t)v->w * (size_t)v->h);
  ts_flow_occlusion(b->back, b->fwd, v->w, v->h, b->occluded);
  ts_guide_position_advect(c->pos, b->back, b->occluded, v->w, v->h, b->pos);
  char path[TS_VIDEO_PATH], path2[TS_VIDEO_PATH];
  if (v->wt.edge > 0) {
    ts_video_chain_file(dir, c->key, t, "edge.png", path, sizeof(path));
    rc = write_edges(v, t, path, err);
  }
  if (rc == 0 && v->wt.position > 0) {
    ts_video_chain_file(dir, c->key, t, "position_x.png", path, sizeof(path));
    ts_video_chain_file(dir, c->key, t, "position_y.png", path2, sizeof(path2));
    rc = write_position(b->pos, v->w, v->h, path, path2, err);
  }
  if (rc == 0 && v->wt.temporal > 0) {
    temporal_guide(v, c, b);
    ts_video_chain_file(dir, c->key, t, "temporal.png", path, sizeof(path));
    rc = write_u8(path, b->px, v->w, v->h, v->channels, err);
    ts_video_chain_file(dir, c->key, t, "temporal_complement.png", path, sizeof(path));
    if (rc == 0) rc = write_u8(path, b->px2, v->w, v->h, v->channels, err);
  }
  return rc;
}

/* The stylize job of frame t of the chain, its inputs and output in dir:
 * the number of inputs. */
static int chain_job(const ts_video *v, const char *dir, chain *c, long t) {
  c->job = v->job;
  int g = job_paths(v, dir, c->key, t, c->in);
  for (int k = 0; k < 1 + 2 * g; k++) c->job.in[k] = c->in[k];
  ts_video_chain_file(dir, c->key, t, "out.png", c->out, sizeof(c->out));
  ts_output_set(&c->job.out, "output", c->out);
  ts_video_chain_file(dir, c->key, t, "error.tif", c->error, sizeof(c->error));
  ts_output_set(&c->job.out, "error_map", c->error);
  if (ts_output_path(&v->job.out, "report") != NULL) {
    ts_video_chain_file(dir, c->key, t, "report.json", c->report, sizeof(c->report));
    ts_output_set(&c->job.out, "report", c->report);
  }
  snprintf(c->name, sizeof(c->name), "frame %ld from key %ld", t, c->key);
  c->job.result_name = c->name;
  if (v->seq.id[0] != '\0' && t != c->key) {
    ts_jobspec_seq *q = &c->job.spec.seq;
    *q = v->seq;
    q->key = c->key;
    q->end = c->last;
    q->frame = t;
  }
  return 1 + 2 * g;
}

/* ---- running the chains ------------------------------------------------ */

/* How long a chain waits for a lost coordinator to come back. */
#define RECONNECT_SECONDS 120

typedef struct {
  const ts_video *v;
  const char *dir;
  ts_search *search; /* embedded */
  ts_conn conn;      /* on a coordinator */
  int connected;
  step_buf b;
} runner;

static const char *direction(const chain *c) { return c->dir > 0 ? "forward" : "backward"; }

/* Reads a job's inputs and runs it here. */
static int run_here(runner *r, const ts_job_cmd *job, char *err) {
  ts_engine_inputs names;
  job->spec.engine->inputs(&job->spec.params, &names);
  ts_image in[TS_ENGINE_MAX_INPUTS] = {0};
  const ts_image *inp[TS_ENGINE_MAX_INPUTS];
  int rc = load_job(job, names.n, in, inp, err);
  if (rc == 0) rc = ts_job_embedded(job, inp, r->search, err);
  free_inputs(in, names.n);
  return rc;
}

/* The coordinator lost (TS_ECONN): a new connection to the same address,
 * tried for RECONNECT_SECONDS. A restarted coordinator takes its spooled
 * jobs up again under their ids, so the chains go on where they were. */
static int reconnect(runner *r, const char *why, char *err) {
  const ts_job_cmd *job = &r->v->job;
  ts_conn_close(&r->conn);
  r->connected = 0;
  fprintf(stderr, "texsyn video: lost the coordinator (%s); trying %s again for up to %d s\n", why, job->server,
          RECONNECT_SECONDS);
  char last[TS_ERR_LEN] = "";
  for (double t0 = ts_now(); ts_now() - t0 < RECONNECT_SECONDS;) {
    if (ts_job_connect(&r->conn, job->server, job->secret_file, last) == 0) {
      r->connected = 1;
      fprintf(stderr, "texsyn video: reconnected to %s\n", job->server);
      return 0;
    }
    nanosleep(&(struct timespec){0, 200000000L}, NULL);
  }
  return ts_error(err, TS_ECONN, "the coordinator at %s did not come back within %d s (%s); the same command with "
                  "the same --write-guides DIR goes on at the next unfinished frame of each chain", job->server,
                  RECONNECT_SECONDS, last);
}

/* Submits the chain's job, again on a new connection if the coordinator
 * went away meanwhile. */
static int submit(runner *r, chain *c, char *err) {
  int rc;
  while ((rc = ts_job_submit(&r->conn, &c->job, &c->id, err)) == TS_ECONN) {
    char why[TS_ERR_LEN];
    snprintf(why, sizeof(why), "%s", err);
    if ((rc = reconnect(r, why, err)) != 0) break;
  }
  return rc;
}

/* Follows the chain's job to its end and fetches its files, across
 * coordinator restarts; a job the new coordinator does not know (its
 * spool lost) is submitted again, once. */
static int finish(runner *r, chain *c, char *err) {
  int resubmitted = 0;
  for (;;) {
    int rc = ts_job_finish(&r->conn, &c->job, c->id, err);
    char why[TS_ERR_LEN];
    snprintf(why, sizeof(why), "%s", err);
    if (rc == TS_ENOENT && !resubmitted && strncmp(err, "no job", 6) == 0) {
      resubmitted = 1;
      fprintf(stderr, "texsyn video: %s: submitting frame %ld from key %ld again\n", why, c->frame + c->dir, c->key);
      rc = submit(r, c, err);
      if (rc == 0) continue;
    }
    if (rc != TS_ECONN) return rc;
    if ((rc = reconnect(r, why, err)) != 0) return rc;
  }
}

/* The chain's next frame: its guides made, its job run (embedded) or
 * submitted (coordinator). */
static int step_start(runner *r, chain *c, char *err) {
  long t = c->frame + c->dir;
  if (!r->v->job.quiet)
    fprintf(stderr, "texsyn video: key %ld %s, frame %ld (%ld of %ld)\n", c->key, direction(c), t,
            labs(t - c->key), labs(c->last - c->key));
  int rc = make_guides(r->v, r->dir, c, t, &r->b, err);
  if (rc != 0) return rc;
  float *pos = c->pos;
  c->pos = r->b.pos;
  r->b.pos = pos;
  uint8_t *luma = c->luma;
  c->luma = r->b.luma;
  r->b.luma = luma;
  chain_job(r->v, r->dir, c, t);
  return r->connected ? submit(r, c, err) : run_here(r, &c->job, err);
}

/* ---- a finished frame on disk ------------------------------------------ */

/* A finished frame's state beside its image and error map: its position
 * guide and the error piled up to it (raw floats), which with the image
 * are all the next frame needs, and the flow to the frame before (the
 * blend's). The piled-up error goes last: its file says the frame is
 * finished (files go in by rename, ts_file_write). */
static int frame_save(const ts_video *v, const char *dir, const chain *c, char *err) {
  size_t n = (size_t)v->w * (size_t)v->h;
  char path[TS_VIDEO_PATH];
  ts_video_chain_file(dir, c->key, c->frame, "pos.raw", path, sizeof(path));
  int rc = ts_video_write_floats(path, c->pos, 2 * n, err);
  ts_video_chain_file(dir, c->key, c->frame, "flow.raw", path, sizeof(path));
  if (rc == 0) rc = ts_video_write_floats(path, c->flow, 2 * n, err);
  ts_video_chain_file(dir, c->key, c->frame, "acc.raw", path, sizeof(path));
  if (rc == 0) rc = ts_video_write_floats(path, c->acc, n, err);
  return rc;
}

static int frame_finished(const char *dir, long key, long t) {
  static const char *const what[] = {"out.png", "error.tif", "pos.raw", "flow.raw", "acc.raw"};
  char path[TS_VIDEO_PATH];
  for (size_t k = 0; k < sizeof(what) / sizeof(what[0]); k++) {
    ts_video_chain_file(dir, key, t, what[k], path, sizeof(path));
    if (access(path, R_OK) != 0) return 0;
  }
  return 1;
}

/* An error map as floats (1 channel, the frames' size). */
static int read_error(const ts_video *v, const char *path, float *e, char *err) {
  ts_image img = {0};
  ts_image_limits limits = {v->job.max_pixels, NULL};
  int rc = ts_image_read(path, &img, &limits, err);
  if (rc == 0 && (img.width != v->w || img.height != v->h || img.channels != 1 || img.type != TS_PIX_F32))
    rc = ts_error(err, TS_EFORMAT, "%s is not a %dx%d float error map", path, v->w, v->h);
  if (rc == 0) memcpy(e, img.pixels, sizeof(float) * (size_t)v->w * (size_t)v->h);
  ts_image_free(&img);
  return rc;
}

/* The chain's next frame done: fetched (coordinator), taken as the frame
 * the following one is warped from, its error piled onto the chain's
 * along the flow (Jamriška et al.: the blend's measure), saved. */
static int step_end(runner *r, chain *c, char *err) {
  const ts_video *v = r->v;
  size_t n = (size_t)v->w * (size_t)v->h;
  int rc = r->connected ? finish(r, c, err) : 0;
  uint8_t *px = rc == 0 ? malloc(n * v->channels) : NULL;
  float *e = rc == 0 ? malloc(sizeof(float) * n) : NULL;
  if (rc == 0 && (px == NULL || e == NULL)) rc = ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) rc = ts_video_read8(v, c->out, px, err);
  if (rc == 0) rc = read_error(v, c->error, e, err);
  for (size_t i = 0; rc == 0 && i < n * v->channels; i++) c->sty[i] = px[i];
  if (rc == 0) {
    ts_flow_warp(c->acc, v->w, v->h, 1, c->flow, r->b.warped);
    for (size_t i = 0; i < n; i++) c->acc[i] = r->b.warped[i] + e[i];
  }
  free(px);
  free(e);
  c->frame += c->dir;
  return rc == 0 ? frame_save(v, r->dir, c, err) : rc;
}

/* A rerun with the same work directory (ts_video_claim said it holds this
 * job's frames): the chain goes on after the last frame of an unbroken
 * run of finished ones from its key. */
static int chain_resume(runner *r, chain *c, char *err) {
  const ts_video *v = r->v;
  size_t n = (size_t)v->w * (size_t)v->h;
  long t = c->key;
  while (t != c->last && frame_finished(r->dir, c->key, t + c->dir)) t += c->dir;
  if (t == c->key) return 0;
  char path[TS_VIDEO_PATH];
  ts_video_chain_file(r->dir, c->key, t, "out.png", path, sizeof(path));
  int rc = ts_video_read8(v, path, r->b.px, err);
  ts_video_chain_file(r->dir, c->key, t, "pos.raw", path, sizeof(path));
  if (rc == 0) rc = ts_video_read_floats(path, c->pos, 2 * n, err);
  ts_video_chain_file(r->dir, c->key, t, "acc.raw", path, sizeof(path));
  if (rc == 0) rc = ts_video_read_floats(path, c->acc, n, err);
  if (rc == 0) rc = read_luma(v, t, c->luma, err);
  for (size_t i = 0; rc == 0 && i < n * v->channels; i++) c->sty[i] = r->b.px[i];
  if (rc != 0) return rc;
  if (!v->job.quiet)
    fprintf(stderr, "texsyn video: key %ld %s: frames %ld..%ld were finished before (kept in %s), going on %s\n",
          c->key, direction(c), c->key + c->dir < t ? c->key + c->dir : t, c->key + c->dir < t ? t : c->key + c->dir,
          r->dir, t == c->last ? "with nothing left to do" : "from there");
  c->frame = t;
  return 0;
}

/* The frames of key k's chains: backward to lo, the frame after the
 * previous key (or the first frame), forward to hi, the frame before the
 * next (or the last). */
static void chain_span(const ts_video *v, int k, long *lo, long *hi) {
  *lo = k > 0 ? v->key[k - 1].frame + 1 : v->fr.first;
  *hi = k + 1 < v->nkeys ? v->key[k + 1].frame - 1 : v->fr.last;
}

uint32_t ts_video_job_count(const ts_video *v) {
  uint32_t n = 0;
  for (int k = 0; k < v->nkeys; k++) {
    long lo, hi, key = v->key[k].frame;
    chain_span(v, k, &lo, &hi);
    n += (uint32_t)((lo < key ? key - lo : 0) + (hi > key ? hi - key : 0));
  }
  return n;
}

/* The chains: per key, backward and forward over its span. */
static int chains_make(const ts_video *v, const char *dir, chain *cs, int *n, char *err) {
  int rc = 0;
  *n = 0;
  for (int k = 0; rc == 0 && k < v->nkeys; k++) {
    long lo, hi, key = v->key[k].frame;
    chain_span(v, k, &lo, &hi);
    if (lo < key) rc = chain_init(v, dir, key, lo, &cs[(*n)++], err);
    if (rc == 0 && hi > key) rc = chain_init(v, dir, key, hi, &cs[(*n)++], err);
  }
  return rc;
}

/* One round: the next frame of every chain not at its end. */
static int round_run(runner *r, chain *cs, int n, int *active, char *err) {
  int rc = 0, started[2 * TS_VIDEO_MAX_KEYS] = {0};
  *active = 0;
  for (int i = 0; rc == 0 && i < n; i++)
    if (cs[i].frame != cs[i].last) {
      rc = step_start(r, &cs[i], err);
      started[i] = rc == 0;
      *active += started[i];
    }
  for (int i = 0; i < n; i++) /* the submitted ones are collected even after a failure */
    if (started[i]) {
      char why[TS_ERR_LEN];
      int rc2 = step_end(r, &cs[i], rc == 0 ? err : why);
      if (rc == 0) rc = rc2;
    }
  return rc;
}

int ts_video_run_chains(const ts_video *v, const char *dir, int resume, char *err) {
  chain *cs = calloc(2 * (size_t)v->nkeys, sizeof(*cs));
  int n = 0, active = 1;
  runner r = {.v = v, .dir = dir};
  int rc = cs != NULL ? step_buf_alloc(&r.b, v, err) : ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) rc = chains_make(v, dir, cs, &n, err);
  for (int i = 0; rc == 0 && resume && i < n; i++) rc = chain_resume(&r, &cs[i], err);
  if (rc == 0 && v->job.server != NULL) {
    rc = ts_job_open(&r.conn, &v->job, err);
    r.connected = rc == 0;
  } else if (rc == 0) {
    rc = ts_search_local_create(&r.search, v->job.threads, NULL, err);
  }
  while (rc == 0 && active > 0) rc = round_run(&r, cs, n, &active, err);
  if (r.connected) ts_conn_close(&r.conn);
  ts_search_destroy(r.search);
  for (int i = 0; i < n; i++) chain_free(&cs[i]);
  free(cs);
  step_buf_free(&r.b);
  return rc;
}

int ts_video_prepare(const ts_video *v, const char *dir, char *err) {
  int rc = v->mask != NULL ? ts_video_mask_prepare(v, dir, err) : 0;
  for (int k = 0; rc == 0 && k < v->nkeys; k++) rc = prepare_key(v, dir, k, err);
  float *pos = rc == 0 ? malloc(sizeof(float) * 2 * v->w * v->h) : NULL;
  if (rc == 0 && pos == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0 && v->wt.position > 0) {
    char px[TS_VIDEO_PATH], py[TS_VIDEO_PATH];
    identity_file(dir, "x", px, sizeof(px));
    identity_file(dir, "y", py, sizeof(py));
    ts_guide_position_key(v->w, v->h, pos);
    rc = write_position(pos, v->w, v->h, px, py, err);
  }
  free(pos);
  if (rc != 0) return rc;
  chain *c = calloc(1, sizeof(*c)); /* its paths: too large for the stack */
  if (c == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  c->key = v->key[0].frame;
  int n = chain_job(v, dir, c, c->key);
  ts_image img[TS_ENGINE_MAX_INPUTS] = {0};
  const ts_image *inp[TS_ENGINE_MAX_INPUTS];
  rc = load_job(&c->job, n, img, inp, err);
  free_inputs(img, n);
  free(c);
  return rc;
}
