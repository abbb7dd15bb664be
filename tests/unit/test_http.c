/* test_http.c - the operations page's pure parts: request paths and the
 * --http address (http_page.c), the secret check (http_auth.c), the
 * rendering of a snapshot (escaping, Prometheus lines) and the thumbnail
 * scaler (thumb.c). The server itself is tested in
 * tests/integration/test_http.py. */
#include <sodium.h>

#include "error.h"
#include "http_auth.h"
#include "http_page.h"
#include "http_seq.h"
#include "thumb.h"
#include "ts_test.h"

/* --- ts_http_route ------------------------------------------------------------ */

static void route_names_the_pages(void **state) {
  (void)state;
  uint64_t id = 0;
  assert_int_equal(ts_http_route("/", &id), TS_HTTP_INDEX);
  assert_int_equal(ts_http_route("/status.json", &id), TS_HTTP_STATUS);
  assert_int_equal(ts_http_route("/metrics", &id), TS_HTTP_METRICS);
  assert_int_equal(ts_http_route("/jobs/42/thumb.png", &id), TS_HTTP_THUMB);
  assert_int_equal(id, 42);
  assert_int_equal(ts_http_route("/jobs/43/small.png", &id), TS_HTTP_SMALL);
  assert_int_equal(id, 43);
  assert_int_equal(ts_http_route("/jobs/18446744073709551615/thumb.png", &id), TS_HTTP_THUMB);
  assert_true(id == UINT64_MAX);
}

static void route_refuses_bad_paths_and_ids(void **state) {
  (void)state;
  const char *bad[] = {"",
                       "/index.html",
                       "/metrics/",
                       "//",
                       "/jobs/",
                       "/jobs//thumb.png",
                       "/jobs/0/thumb.png",
                       "/jobs/007/thumb.png",
                       "/jobs/-1/thumb.png",
                       "/jobs/+1/thumb.png",
                       "/jobs/1x/thumb.png",
                       "/jobs/18446744073709551616/thumb.png",
                       "/jobs/1/thumb.png/",
                       "/jobs/1/thumb.gif",
                       "/jobs/1/small.png/",
                       "/jobs/01/small.png",
                       "/jobs/1/../../etc/passwd"};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    uint64_t id = 7;
    assert_int_equal(ts_http_route(bad[i], &id), TS_HTTP_NOT_FOUND);
  }
}

/* --- ts_http_listen_addr ------------------------------------------------------- */

static void listen_addr_defaults_to_loopback(void **state) {
  (void)state;
  char out[128], host[64], err[TS_ERR_LEN];
  assert_int_equal(ts_http_listen_addr("8080", out, sizeof(out), host, sizeof(host), err), 0);
  assert_string_equal(out, "127.0.0.1:8080");
  assert_string_equal(host, "127.0.0.1");
  assert_int_equal(ts_http_listen_addr(":0", out, sizeof(out), host, sizeof(host), err), 0);
  assert_string_equal(out, "127.0.0.1:0");
  assert_int_equal(ts_http_listen_addr("0.0.0.0:9100", out, sizeof(out), host, sizeof(host), err), 0);
  assert_string_equal(out, "0.0.0.0:9100");
  assert_string_equal(host, "0.0.0.0");
  assert_int_equal(ts_http_listen_addr("[::1]:9100", out, sizeof(out), host, sizeof(host), err), 0);
  assert_string_equal(host, "::1");
}

static void listen_addr_names_what_is_wrong(void **state) {
  (void)state;
  char out[128], host[64], err[TS_ERR_LEN];
  assert_int_equal(ts_http_listen_addr("web", out, sizeof(out), host, sizeof(host), err), TS_EINVAL);
  assert_non_null(strstr(err, "--http web"));
  assert_non_null(strstr(err, "port must be 0..65535"));
  assert_int_equal(ts_http_listen_addr("1.2.3.4:65536", out, sizeof(out), host, sizeof(host), err), TS_EINVAL);
  char small[8];
  assert_int_equal(ts_http_listen_addr("10.0.0.1:80", small, sizeof(small), host, sizeof(host), err), TS_EINVAL);
  assert_non_null(strstr(err, "too long"));
}

/* --- ts_http_auth_check -------------------------------------------------------- */

static void secret_of(ts_auth *a, const char *s) {
  char err[TS_ERR_LEN];
  assert_int_equal(ts_auth_init(err), 0);
  memset(a, 0, sizeof(*a));
  a->enabled = 1;
  a->len = strlen(s);
  memcpy(a->secret, s, a->len);
}

static const char *basic(const char *userpass, char *buf, size_t cap) {
  strcpy(buf, "Basic ");
  sodium_bin2base64(buf + 6, cap - 6, (const unsigned char *)userpass, strlen(userpass),
                    sodium_base64_VARIANT_ORIGINAL);
  return buf;
}

static void auth_takes_basic_and_bearer_with_the_secret(void **state) {
  (void)state;
  ts_auth a;
  secret_of(&a, "open:sesame");
  char err[TS_ERR_LEN], h[256];
  assert_int_equal(ts_http_auth_check(&a, basic("ops:open:sesame", h, sizeof(h)), err), 0);
  assert_int_equal(ts_http_auth_check(&a, basic(":open:sesame", h, sizeof(h)), err), 0); /* any user */
  h[0] = 'b'; /* the scheme is case-insensitive */
  assert_int_equal(ts_http_auth_check(&a, h, err), 0);
  assert_int_equal(ts_http_auth_check(&a, "Bearer open:sesame", err), 0);
}

static void auth_refuses_anything_else(void **state) {
  (void)state;
  ts_auth a;
  secret_of(&a, "sesame");
  char err[TS_ERR_LEN], h[256];
  assert_int_equal(ts_http_auth_check(&a, NULL, err), TS_EAUTH);
  assert_non_null(strstr(err, "needs a page key or an admin key"));
  const char *wrong[] = {"Bearer sesam", "Bearer sesame ", "Bearer Sesame", "Bearer ", "Digest sesame", "sesame", ""};
  for (size_t i = 0; i < sizeof(wrong) / sizeof(wrong[0]); i++)
    assert_int_equal(ts_http_auth_check(&a, wrong[i], err), TS_EAUTH);
  assert_int_equal(ts_http_auth_check(&a, basic("ops:sesam", h, sizeof(h)), err), TS_EAUTH);
  assert_string_equal(err, "wrong secret");
  assert_int_equal(ts_http_auth_check(&a, basic("sesame", h, sizeof(h)), err), TS_EAUTH); /* no ':' */
  assert_non_null(strstr(err, "':'"));
  assert_int_equal(ts_http_auth_check(&a, "Basic !!!notbase64", err), TS_EAUTH);
  assert_non_null(strstr(err, "base64"));
  char *huge = malloc(TS_HTTP_AUTH_HEADER_MAX + 16);
  assert_non_null(huge);
  memset(huge, 'A', TS_HTTP_AUTH_HEADER_MAX + 15);
  memcpy(huge, "Basic ", 6);
  huge[TS_HTTP_AUTH_HEADER_MAX + 15] = '\0';
  assert_int_equal(ts_http_auth_check(&a, huge, err), TS_EAUTH);
  assert_non_null(strstr(err, "too long"));
  free(huge);
}

/* --- rendering ----------------------------------------------------------------- */

/* A queue with one done and one running job, and one worker whose address
 * carries characters every format must escape. */
static void snapshot(ts_http_snapshot *s, ts_job_status jobs[2], ts_worker_info *w) {
  memset(s, 0, sizeof(*s));
  memset(jobs, 0, sizeof(ts_job_status) * 2);
  memset(w, 0, sizeof(*w));
  jobs[0] = (ts_job_status){.id = 3, .state = TS_JOB_DONE, .permille = 1000, .eta_ms = UINT32_MAX};
  jobs[1] = (ts_job_status){.id = 4, .state = TS_JOB_RUNNING, .level = 1, .levels = 4, .permille = 512,
                            .eta_ms = 61500, .workers = 1};
  snprintf(jobs[1].text, sizeof(jobs[1].text), "<script>\"x\"\n");
  snprintf(jobs[0].engine, sizeof(jobs[0].engine), "mrf");
  snprintf(jobs[1].engine, sizeof(jobs[1].engine), "mrf");
  snprintf(w->addr, sizeof(w->addr), "h\"o\\st\n:1");
  w->state = 1; /* ready */
  w->calibrated = 2500000000u;
  w->rate = 2000000000u;
  w->share = 1000;
  w->batches = 17;
  w->threads = 2;
  s->uptime = 3725;
  s->threads = 2;
  s->stats = (ts_cluster_stats){1, 2000000000u, 1234, 56789};
  s->counts[TS_JOB_RUNNING] = 1;
  s->counts[TS_JOB_DONE] = 1;
  s->have_current = 1;
  s->cur = jobs[1];
  s->jobs = jobs;
  s->njobs = 2;
  s->workers = w;
  s->nworkers = 1;
}

static void metrics_are_prometheus_text(void **state) {
  (void)state;
  ts_http_snapshot s;
  ts_job_status jobs[2];
  ts_worker_info w;
  snapshot(&s, jobs, &w);
  ts_text t;
  ts_text_init(&t);
  ts_http_render_metrics(&t, &s);
  assert_false(t.failed);
  assert_int_equal(strlen(t.buf), t.len);
  const char *want[] = {"# TYPE texsyn_queries_total counter\ntexsyn_queries_total 56789\n",
                        "# TYPE texsyn_batches_total counter\ntexsyn_batches_total 1234\n",
                        "texsyn_uptime_seconds 3725\n",
                        "texsyn_jobs{state=\"running\"} 1\n",
                        "texsyn_jobs{state=\"queued\"} 0\n",
                        "texsyn_current_job_id 4\n",
                        "texsyn_current_job_progress_ratio 0.51200000000000001\n",
                        "texsyn_current_job_eta_seconds 61.500\n",
                        "texsyn_worker_slice_share_ratio{worker=\"h\\\"o\\\\st\\n:1\"} 1\n",
                        "texsyn_worker_state{worker=\"h\\\"o\\\\st\\n:1\",state=\"ready\"} 1\n",
                        "texsyn_worker_batches_total{worker=\"h\\\"o\\\\st\\n:1\"} 17\n"};
  for (size_t i = 0; i < sizeof(want) / sizeof(want[0]); i++) {
    if (strstr(t.buf, want[i]) == NULL) fail_msg("missing %s in:\n%s", want[i], t.buf);
  }
  assert_null(strstr(t.buf, "\n\n"));
  ts_text_free(&t);
  /* A failed entry of the same address (it joined again) gives no second series. */
  ts_worker_info two[2] = {w, w};
  two[0].state = 2; /* failed */
  s.workers = two;
  s.nworkers = 2;
  ts_http_render_metrics(&t, &s);
  const char *series = "texsyn_worker_batches_total{worker=";
  const char *first = strstr(t.buf, series);
  assert_non_null(first);
  assert_null(strstr(first + 1, series));
  assert_null(strstr(t.buf, "\",state=\"failed\""));
  s.cur.eta_ms = UINT32_MAX;
  ts_text_free(&t);
  ts_http_render_metrics(&t, &s);
  assert_non_null(strstr(t.buf, "texsyn_current_job_eta_seconds NaN\n"));
  ts_text_free(&t);
}

static void html_and_json_escape_what_they_show(void **state) {
  (void)state;
  ts_http_snapshot s;
  ts_job_status jobs[2];
  ts_worker_info w;
  snapshot(&s, jobs, &w);
  ts_text t;
  ts_text_init(&t);
  ts_http_render_html(&t, &s, 2);
  assert_false(t.failed);
  assert_null(strstr(t.buf, "<script>"));
  assert_non_null(strstr(t.buf, "level 3 of 4: &lt;script&gt;&quot;x&quot;"));
  assert_non_null(strstr(t.buf, "<progress max=\"1000\" value=\"512\">51.2%</progress> <span class=percent>51.2</span>%"));
  assert_non_null(strstr(t.buf, "<td class=n>1 min 2 s</td>")); /* 61.5 s, rounded up */
  assert_non_null(strstr(t.buf, "<img src=\"/jobs/3/thumb.png\""));
  /* Running: its growing preview if it has one (preview.h), else the 404 removes it. */
  assert_non_null(strstr(t.buf, "<img src=\"/jobs/4/thumb.png\" alt=\"job 4 result\" onerror=\"this.remove()\">"));
  assert_non_null(strstr(t.buf, "<td>h&quot;o\\st\n:1</td><td class=state>ready</td>"));
  assert_non_null(strstr(t.buf, "2.50 GB/s"));
  assert_non_null(strstr(t.buf, "100.0%"));
  assert_true(strstr(t.buf, "id=\"job-4\"") < strstr(t.buf, "id=\"job-3\"")); /* newest first */
  ts_text_free(&t);
  ts_http_render_json(&t, &s);
  assert_non_null(strstr(t.buf, "\"text\":\"<script>\\\"x\\\"\\u000a\""));
  assert_non_null(strstr(t.buf, "\"worker\":\"h\\\"o\\\\st\\u000a:1\""));
  assert_non_null(strstr(t.buf, "{\"id\":4,\"engine\":\"mrf\",\"state\":\"running\",\"permille\":512"));
  assert_non_null(strstr(t.buf, "\"eta_s\":61.5}"));
  assert_non_null(strstr(t.buf, "\"eta_s\":null}"));
  ts_text_free(&t);
}

static void text_grows_past_its_first_block(void **state) {
  (void)state;
  ts_text t;
  ts_text_init(&t);
  for (int i = 0; i < 5000; i++) ts_text_add(&t, "%04d,", i % 10000);
  assert_false(t.failed);
  assert_int_equal(t.len, 25000);
  assert_memory_equal(t.buf + 24995, "4999,", 5);
  ts_text_free(&t);
  assert_null(t.buf);
}

/* --- sequences ------------------------------------------------------------------- */

static ts_job_frame frame_job(uint64_t id, int state, const char *seq, long key, long end, long frame) {
  ts_job_frame f = {.id = id, .state = (uint8_t)state, .permille = state == TS_JOB_RUNNING ? 450 : 0};
  snprintf(f.seq.id, sizeof(f.seq.id), "%s", seq);
  snprintf(f.seq.name, sizeof(f.seq.name), seq[15] == 'a' ? "<a>_%%04d.png" : "b_%%04d.png");
  f.seq.first = 1;
  f.seq.last = 8;
  f.seq.jobs = 7;
  f.seq.key = key;
  f.seq.end = end;
  f.seq.frame = frame;
  return f;
}

#define SEQ_A "00000000000000aa"
#define SEQ_B "00000000000000bb"

/* Two runs' frames, oldest first as the jobs list them: run A's chains
 * from key 4 (backward to 1, forward to 8), its frame 5 submitted again
 * (job 9, queued) after it finished (job 2); run B, newer, one frame. */
static void sequence_frames(ts_job_frame f[7]) {
  f[0] = frame_job(1, TS_JOB_DONE, SEQ_A, 4, 1, 3);
  f[1] = frame_job(2, TS_JOB_DONE, SEQ_A, 4, 8, 5);
  f[2] = frame_job(5, TS_JOB_QUEUED, SEQ_A, 4, 1, 2);
  f[3] = frame_job(6, TS_JOB_RUNNING, SEQ_A, 4, 8, 6);
  f[4] = frame_job(9, TS_JOB_QUEUED, SEQ_A, 4, 8, 5);
  f[5] = frame_job(10, TS_JOB_DONE, SEQ_B, 1, 8, 2);
  f[6] = frame_job(11, TS_JOB_FAILED, SEQ_B, 1, 8, 3);
}

static void sequences_group_chains_and_frames(void **state) {
  (void)state;
  ts_job_frame f[7];
  sequence_frames(f);
  ts_http_seqs g;
  assert_int_equal(ts_http_seqs_make(f, 7, &g), 0);
  assert_int_equal(g.nseq, 2);
  assert_int_equal(g.ncells, 6); /* frame 5 once */
  assert_string_equal(g.cell[g.seq[0].from]->seq.id, SEQ_B); /* the newest run first */
  assert_int_equal(g.seq[0].done, 1);
  const ts_http_seq *a = &g.seq[1];
  assert_int_equal(a->to - a->from, 4);
  assert_int_equal(a->done, 2);
  /* Chains by key, then end (backward first); frames in frame order; the
   * finished job of a frame shown over a newer one. */
  const uint64_t want[4] = {5, 1, 2, 6};
  for (uint32_t i = 0; i < 4; i++) assert_int_equal(g.cell[a->from + i]->id, want[i]);
  ts_http_seqs_free(&g);
  assert_int_equal(ts_http_seqs_make(f, 0, &g), 0);
  assert_int_equal(g.nseq, 0);
}

static void sequences_on_the_page_and_in_json(void **state) {
  (void)state;
  ts_http_snapshot s;
  ts_job_status jobs[2];
  ts_worker_info w;
  ts_job_frame f[7];
  snapshot(&s, jobs, &w);
  ts_text t;
  ts_text_init(&t);
  ts_http_render_html(&t, &s, 2);
  assert_null(strstr(t.buf, "Sequences")); /* none: no section */
  ts_text_free(&t);
  sequence_frames(f);
  s.frames = f;
  s.nframes = 7;
  ts_http_render_html(&t, &s, 2);
  assert_false(t.failed);
  const char *b = strstr(t.buf, "<section class=\"sequence\" data-id=\"" SEQ_B "\"><h3>b_%04d.png</h3>");
  const char *a = strstr(t.buf, "<section class=\"sequence\" data-id=\"" SEQ_A "\"><h3>&lt;a&gt;_%04d.png</h3>");
  assert_non_null(a);
  assert_non_null(b);
  assert_true(b < a && a < strstr(t.buf, "<h2>Jobs</h2>"));
  const char *want[] = {
      "<span class=\"done\">2</span> of <span class=\"jobs\">7</span> frames stylized",
      "<tr class=\"chain\" data-key=\"4\" data-end=\"1\"><td>key 4 backward</td><td>1..3</td><td class=n>1 of 3</td>"
      "<td class=strip><span class=\"frame queued\" data-frame=\"2\" data-job=\"5\" title=\"frame 2 (job 5): queued\">2"
      "</span><a href=\"/jobs/1/thumb.png\"><img class=\"frame\" data-frame=\"3\" data-job=\"1\" "
      "src=\"/jobs/1/small.png\" title=\"frame 3 (job 1)\" alt=\"frame 3\"></a></td></tr>",
      "<td>key 4 forward</td><td>5..8</td><td class=n>1 of 4</td>",
      "<img class=\"frame\" data-frame=\"5\" data-job=\"2\"",
      "<span class=\"frame running\" data-frame=\"6\" data-job=\"6\" title=\"frame 6 (job 6): running 45.0%\">6</span>",
      "<span class=\"frame failed\" data-frame=\"3\" data-job=\"11\""};
  for (size_t i = 0; i < sizeof(want) / sizeof(want[0]); i++)
    if (strstr(t.buf, want[i]) == NULL) fail_msg("missing %s in:\n%s", want[i], t.buf);
  assert_null(strstr(t.buf, "data-job=\"9\""));
  ts_text_free(&t);
  ts_http_render_json(&t, &s);
  assert_false(t.failed);
  const char *json = "\"sequences\":[{\"id\":\"" SEQ_B "\",\"name\":\"b_%04d.png\",\"frames\":[1,8],\"jobs\":7,"
                     "\"done\":1,\"chains\":[{\"key\":1,\"end\":8,\"direction\":\"forward\",\"done\":1,\"frames\":["
                     "{\"frame\":2,\"job\":10,\"state\":\"done\",\"permille\":0},"
                     "{\"frame\":3,\"job\":11,\"state\":\"failed\",\"permille\":0}]}]},"
                     "{\"id\":\"" SEQ_A "\",\"name\":\"<a>_%04d.png\",\"frames\":[1,8],\"jobs\":7,\"done\":2,"
                     "\"chains\":[{\"key\":4,\"end\":1,\"direction\":\"backward\",\"done\":1,";
  if (strstr(t.buf, json) == NULL) fail_msg("missing %s in:\n%s", json, t.buf);
  ts_text_free(&t);
}

/* --- ts_thumb_scale -------------------------------------------------------------- */

static void thumb_averages_boxes_and_keeps_the_aspect(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  ts_image src, dst;
  assert_int_equal(ts_image_alloc(&src, 4, 2, 1, TS_PIX_U8, err), 0);
  const uint8_t px[8] = {0, 255, 10, 20, 255, 0, 30, 40};
  memcpy(src.pixels, px, sizeof(px));
  assert_int_equal(ts_thumb_scale(&src, 2, &dst, err), 0);
  assert_int_equal(dst.width, 2);
  assert_int_equal(dst.height, 1);
  assert_int_equal(dst.type, TS_PIX_U8);
  const uint8_t *d = dst.pixels;
  assert_int_equal(d[0], 128); /* (0 + 255 + 255 + 0) / 4 = 127.5 */
  assert_int_equal(d[1], 25);
  ts_image_free(&dst);
  assert_int_equal(ts_thumb_scale(&src, 160, &dst, err), 0); /* never enlarged */
  assert_int_equal(dst.width, 4);
  assert_int_equal(dst.height, 2);
  assert_memory_equal(dst.pixels, px, sizeof(px));
  ts_image_free(&dst);
  assert_int_equal(ts_thumb_scale(&src, 0, &dst, err), TS_EINVAL);
  ts_image_free(&src);
}

static void thumb_of_a_strip_keeps_a_pixel_and_channels(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  ts_image src, dst;
  assert_int_equal(ts_image_alloc(&src, 1000, 3, 3, TS_PIX_F32, err), 0);
  float *f = src.pixels;
  for (int i = 0; i < 1000 * 3 * 3; i++) f[i] = i % 3 == 0 ? 2.0f : i % 3 == 1 ? -1.0f : 0.5f;
  assert_int_equal(ts_thumb_scale(&src, 160, &dst, err), 0);
  assert_int_equal(dst.width, 160);
  assert_int_equal(dst.height, 1);
  assert_int_equal(dst.channels, 3);
  const uint8_t *d = dst.pixels;
  assert_int_equal(d[0], 255); /* floats clamped to [0, 1] */
  assert_int_equal(d[1], 0);
  assert_int_equal(d[2], 128);
  ts_image_free(&dst);
  ts_image_free(&src);
}

static void thumb_keeps_the_first_four_of_more_channels(void **state) {
  (void)state;
  char err[TS_ERR_LEN];
  ts_image src, dst;
  assert_int_equal(ts_image_alloc(&src, 2, 2, 6, TS_PIX_U16, err), 0);
  uint16_t *p = src.pixels;
  for (int i = 0; i < 2 * 2 * 6; i++) p[i] = (uint16_t)(i % 6 * 257 * 40);
  assert_int_equal(ts_thumb_scale(&src, 1, &dst, err), 0);
  assert_int_equal(dst.width, 1);
  assert_int_equal(dst.channels, 4);
  assert_memory_equal(dst.pixels, ((const uint8_t[]){0, 40, 80, 120}), 4);
  ts_image_free(&dst);
  ts_image_free(&src);
}

/* A client's or a worker's key opens the data plane: the page refuses it
 * even when it is given whole. */
static void auth_refuses_data_plane_keys(void **state) {
  (void)state;
  ts_auth a;
  char err[TS_ERR_LEN];
  const uint8_t kinds[] = {TS_KEY_CLIENT, TS_KEY_WORKER};
  for (size_t i = 0; i < sizeof(kinds); i++) {
    secret_of(&a, "texsyn:client:alice:0123");
    a.who.kind = kinds[i];
    assert_int_equal(ts_http_auth_check(&a, "Bearer texsyn:client:alice:0123", err), TS_EAUTH);
  }
  a.who.kind = TS_KEY_PAGE;
  assert_int_equal(ts_http_auth_check(&a, "Bearer texsyn:client:alice:0123", err), 0);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(route_names_the_pages),
    cmocka_unit_test(route_refuses_bad_paths_and_ids),
    cmocka_unit_test(listen_addr_defaults_to_loopback),
    cmocka_unit_test(listen_addr_names_what_is_wrong),
    cmocka_unit_test(auth_takes_basic_and_bearer_with_the_secret),
    cmocka_unit_test(auth_refuses_anything_else),
cmocka_unit_test(auth_refuses_data_plane_keys),
    cmocka_unit_test(metrics_are_prometheus_text),
    cmocka_unit_test(html_and_json_escape_what_they_show),
    cmocka_unit_test(text_grows_past_its_first_block),
    cmocka_unit_test(sequences_group_chains_and_frames),
    cmocka_unit_test(sequences_on_the_page_and_in_json),
    cmocka_unit_test(thumb_averages_boxes_and_keeps_the_aspect),
    cmocka_unit_test(thumb_of_a_strip_keeps_a_pixel_and_channels),
    cmocka_unit_test(thumb_keeps_the_first_four_of_more_channels),
};

TS_TEST_MAIN(tests)
