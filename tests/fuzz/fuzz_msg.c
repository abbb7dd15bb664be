/* fuzz_msg.c - libFuzzer target for every message-body reader and the job
 * spec parser: the first input byte picks the reader, the rest is the
 * payload. A reader that accepts a payload must hand out pointers and
 * counts inside it; any crash or sanitizer report is a bug. Build and run:
 * make fuzz. */
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "jobspec.h"
#include "msg.h"
#include "wfield.h"

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size);

static void check_inside(const void *p, size_t n, const uint8_t *base, size_t len) {
  const uint8_t *q = p;
  if (p != NULL && (q < base || q + n > base + len)) abort();
}

/* Rows [y0, k0) at r.lo and [k1, y1) at r.hi lie in the frame. */
static void check_rows(const ts_frame *f, ts_slice_rows r, size_t row, int y0, int y1, int k0, int k1) {
  check_inside(r.lo, row * (size_t)(k0 - y0), f->payload, f->len);
  check_inside(r.hi, row * (size_t)(y1 - k1), f->payload, f->len);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
  if (size == 0) return 0;
  ts_frame f = {data[0], 1, (uint32_t)(size - 1), data + 1};
  char err[TS_ERR_LEN];
  /* 0xF0 and 0xF1 pick the PatchMatch messages, 0xF2 the fetch range
   * (added after the seeds of the others, whose first bytes keep their
   * meaning). */
  switch (data[0] == 0xF0 ? 14 : data[0] == 0xF1 ? 15 : data[0] == 0xF2 ? 16 : data[0] % 14) {
  case 0: { ts_msg_ident m; ts_msg_ident_read(&f, &m, err); break; }
  case 1: { ts_msg_calib_req m; ts_msg_calib_req_read(&f, &m, err); ts_msg_calib c; ts_msg_calib_read(&f, &c, err); break; }
  case 2: {
    ts_slice_desc m;
    if (ts_msg_slice_read(&f, &m, err) == 0) {
      size_t w = (size_t)m.w, cw = (size_t)m.cw;
      for (int p = 0; p < m.win.nplanes[TS_SRC_FINE] && !m.fine_from_image; p++)
        check_rows(&f, m.fine[p], w, m.fy0, m.fy1, m.kfy0, m.kfy1);
      for (int p = 0; p < m.win.nplanes[TS_SRC_COARSE]; p++)
        check_rows(&f, m.coarse[p], cw, m.cy0, m.cy1, m.kcy0, m.kcy1);
      if (m.labelled == TS_SLICE_LABELS_ROWS) check_rows(&f, m.labels, w, m.ay0, m.ay1, m.kay0, m.kay1);
      if (m.masked) check_rows(&f, m.valid, w, m.ay0, m.ay1, m.kay0, m.kay1);
      if (m.usage == TS_SLICE_USAGE_COUNTS) check_rows(&f, m.counts, 4 * w, m.fy0, m.fy1, m.kfy0, m.kfy1);
      uint64_t ncent = 0;
      for (int c = 0; c < m.nclass && m.lbg.mode != TS_LBG_OFF; c++) ncent += m.lbg.npart[c];
      check_inside(m.lbg.cent, (size_t)(ncent * m.lbg.vbytes), f.payload, f.len);
    }
    break;
  }
  case 3: {
    ts_msg_query m;
    if (ts_msg_query_read(&f, &m, err) == 0) {
      check_inside(m.pos, (size_t)m.nq * 4, f.payload, f.len);
      check_inside(m.klass, m.nq, f.payload, f.len);
      check_inside(m.places, (size_t)m.nplace * TS_PLACE_BYTES, f.payload, f.len);
      for (uint32_t i = 0; i < m.nq; i++) (void)ts_msg_pos_at(&m, i);
    }
    break;
  }
  case 4: {
    ts_msg_answer m;
    if (ts_msg_answer_read(&f, &m, err) == 0)
      for (uint32_t i = 0; i < m.nq; i++) {
        ts_l1_best b;
        ts_msg_result_at(&m, i, &b);
      }
    break;
  }
  case 5: { ts_msg_unload m; ts_msg_unload_read(&f, &m, err); ts_msg_loaded l; ts_msg_loaded_read(&f, &l, err); break; }
  case 6: { ts_msg_error m; ts_msg_error_read(&f, &m, err); break; }
  case 7: {
    ts_msg_submit m;
    if (ts_msg_submit_read(&f, &m, err) == 0) check_inside(m.ref, m.ref_len, f.payload, f.len);
    break;
  }
  case 8: {
    ts_msg_status_req r;
    ts_msg_status_req_read(&f, &r, err);
    ts_job_status s[4];
    uint32_t n;
    ts_msg_status_read(&f, s, 4, &n, err);
    uint64_t id;
    ts_msg_jobid_read(&f, &id, err);
    break;
  }
  case 9: {
    ts_msg_files m;
    if (ts_msg_files_read(&f, &m, err) == 0)
      for (uint32_t i = 0; i < m.n; i++) check_inside(m.data[i], m.len[i], f.payload, f.len);
    break;
  }
  case 16: { ts_msg_range m; ts_msg_range_read(&f, &m, err); break; }
  case 10: { ts_worker_info w[4]; uint32_t n; ts_msg_pool_read(&f, w, 4, &n, err); break; }
  case 11: { ts_jobspec s; ts_jobspec_parse((const char *)f.payload, f.len, &s, err); break; }
  case 12: { ts_msg_auth m; ts_msg_auth_read(&f, &m, err); break; }
  case 13: {
    /* 'R' as the worker takes it: decoded, then loaded into a replica */
    ts_msg_image m;
    if (ts_msg_image_read(&f, &m, err) == 0 && m.op == TS_IMAGE_LOAD) {
      size_t npx = (size_t)m.d.w * (size_t)m.d.h;
      for (int p = 0; p < m.d.nplanes; p++) check_inside(m.d.fine[p], npx, f.payload, f.len);
      check_inside(m.d.done, npx, f.payload, f.len);
      check_inside(m.copy_le, m.copy_le != NULL ? 8 * npx : 0, f.payload, f.len);
      uint32_t *copy = m.copy_le != NULL ? malloc(8 * npx) : NULL; /* none: the image keeps no copy map */
      if (copy != NULL) memcpy(copy, m.copy_le, 8 * npx);
      m.d.copy = copy;
      ts_replica r;
      if (ts_replica_init(&r, &m.d, err) == 0) ts_replica_free(&r);
      free(copy);
    }
    break;
  }
  case 14: {
    /* 'G' as the worker takes it: decoded, then packed */
    ts_msg_field *m = malloc(sizeof(*m));
    if (m != NULL && ts_msg_field_read(&f, m, err) == 0) {
      for (int p = 0; p < m->nplanes; p++) check_inside(m->plane[p], (size_t)m->w * (size_t)m->h, f.payload, f.len);
      ts_wfields fs = {0};
      ts_wfield_load(&fs, m, 1, err);
      ts_wfield_drop(&fs, TS_UNLOAD_ALL);
    }
    free(m);
    ts_msg_pass_answer a;
    if (ts_msg_field_ack_read(&f, &(uint32_t){0}, err) == 0) break;
    if (ts_msg_pass_answer_read(&f, &a, err) == 0) check_inside(a.entries, 4 * (size_t)a.nentries, f.payload, f.len);
    break;
  }
  case 15: {
    ts_msg_pass m;
    if (ts_msg_pass_read(&f, &m, err) == 0) {
      check_inside(m.tiles_le, 4 * (size_t)m.ntiles, f.payload, f.len);
      check_inside(m.field_le, 4 * (size_t)m.tw * m.th, f.payload, f.len);
    }
    break;
  }
  }
  return 0;
}
