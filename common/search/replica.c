/* replica.c - see replica.h. */
#include "replica.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"

static void planes_free(ts_plane *p) {
  for (int k = 0; k < TS_WIN_MAX_PLANES; k++) ts_plane_free(&p[k]);
}

void ts_replica_free(ts_replica *r) {
  planes_free(r->fine);
  planes_free(r->coarse);
  planes_free(r->ref);
  free(r->copy);
  free(r->done);
  memset(r, 0, sizeof(*r));
}

static int size_ok(int w, int h) {
  return w >= 1 && h >= 1 && (uint64_t)w * (uint64_t)h <= TS_REPLICA_MAX_PIXELS;
}

/* n planes of w x h copied from src (NULL: zero). */
static int planes_copy(ts_plane *dst, int n, int w, int h, const uint8_t *const *src) {
  for (int k = 0; k < n; k++) {
    if (ts_plane_alloc(&dst[k], w, h) != 0) return TS_ENOMEM;
    if (src != NULL && src[k] != NULL) memcpy(dst[k].px, src[k], (size_t)w * (size_t)h);
    else memset(dst[k].px, 0, (size_t)w * (size_t)h);
  }
  return 0;
}

static void point_planes(ts_replica *r) {
  for (int k = 0; k < r->nplanes; k++) {
    r->planes.fine[k] = &r->fine[k];
    r->planes.coarse[k] = r->coarse[k].px ? &r->coarse[k] : NULL;
  }
}

static int check_desc(const ts_replica_desc *d, char *err) {
  if (d->nplanes < 1 || d->nplanes > TS_WIN_MAX_PLANES)
    return ts_error(err, TS_EINVAL, "a query image of %d planes: need 1..%d", d->nplanes, TS_WIN_MAX_PLANES);
  if (!size_ok(d->w, d->h))
    return ts_error(err, TS_EINVAL, "a query image of %dx%d: need 1..%u pixels", d->w, d->h, TS_REPLICA_MAX_PIXELS);
  if ((d->cw || d->ch) && !size_ok(d->cw, d->ch))
    return ts_error(err, TS_EINVAL, "coarse planes of %dx%d: need 1..%u pixels", d->cw, d->ch, TS_REPLICA_MAX_PIXELS);
  if (d->bounded != 0 && d->bounded != 1) return ts_error(err, TS_EINVAL, "a query image's bounded flag is %d", d->bounded);
  size_t npx = (size_t)d->w * (size_t)d->h;
  for (size_t i = 0; d->done != NULL && i < npx; i++)
    if (d->done[i] > TS_DONE_CLOSED)
      return ts_error(err, TS_EINVAL, "pixel %zu of a query image has state %u: need 0..%d", i, d->done[i],
                      TS_DONE_CLOSED);
  if (d->block == 0) return 0;
  if (d->block < 1 || d->block > TS_WIN_MAX_REACH)
    return ts_error(err, TS_EINVAL, "placed blocks of side %d: need 1..%d", d->block, TS_WIN_MAX_REACH);
  if (!size_ok(d->rw, d->rh))
    return ts_error(err, TS_EINVAL, "a reference of %dx%d to copy from: need 1..%u pixels", d->rw, d->rh,
                    TS_REPLICA_MAX_PIXELS);
  for (size_t i = 0; d->copy != NULL && i < npx; i++)
    if (d->copy[2 * i] >= (uint32_t)d->rw || d->copy[2 * i + 1] >= (uint32_t)d->rh)
      return ts_error(err, TS_EINVAL, "the copy map points outside the %dx%d reference at pixel %zu", d->rw, d->rh,
                      i);
  return 0;
}

int ts_replica_init(ts_replica *r, const ts_replica_desc *d, char *err) {
  memset(r, 0, sizeof(*r));
  int rc = check_desc(d, err);
  if (rc != 0) return rc;
  r->w = d->w;
  r->h = d->h;
  r->nplanes = d->nplanes;
  r->block = d->block;
  r->bounded = d->bounded;
  size_t npx = (size_t)d->w * (size_t)d->h;
  rc = planes_copy(r->fine, d->nplanes, d->w, d->h, d->fine);
  if (rc == 0 && d->cw) rc = planes_copy(r->coarse, d->nplanes, d->cw, d->ch, d->coarse);
  if (rc == 0 && (r->done = calloc(npx, 1)) == NULL) rc = TS_ENOMEM;
  if (rc == 0 && d->done) memcpy(r->done, d->done, npx);
  if (rc == 0 && d->block) {
    rc = planes_copy(r->ref, d->nplanes, d->rw, d->rh, d->ref);
    if (rc == 0 && d->copy != NULL && (r->copy = malloc(sizeof(uint32_t) * 2 * npx)) == NULL) rc = TS_ENOMEM;
    if (rc == 0 && d->copy != NULL) memcpy(r->copy, d->copy, sizeof(uint32_t) * 2 * npx);
  }
  if (rc != 0) {
    ts_replica_free(r);
    return ts_error(err, rc, "out of memory for a %dx%d query image", d->w, d->h);
  }
  point_planes(r);
  return 0;
}

void ts_copy_predict(const uint32_t *prev, int pw, int ph, int w, int h, int rw, int rh, int x, int y, int *sx,
                     int *sy) {
  long cx = (long)x * pw / w, cy = (long)y * ph / h, co = cy * pw + cx;
  long px = 2 * (long)prev[2 * co] + (x - 2 * cx), py = 2 * (long)prev[2 * co + 1] + (y - 2 * cy);
  *sx = (int)(px < 0 ? 0 : px >= rw ? rw - 1 : px);
  *sy = (int)(py < 0 ? 0 : py >= rh ? rh - 1 : py);
}

int ts_replica_next_level(ts_replica *r, int w, int h, int rw, int rh, const uint8_t *const *ref, char *err) {
  if (r->copy == NULL) return ts_error(err, TS_EINVAL, "a query image without a copy map has no next level");
  if (!size_ok(w, h) || !size_ok(rw, rh))
    return ts_error(err, TS_EINVAL, "a next level of %dx%d from a %dx%d reference: need 1..%u pixels", w, h, rw, rh,
                    TS_REPLICA_MAX_PIXELS);
  ts_plane nref[TS_WIN_MAX_PLANES], nfine[TS_WIN_MAX_PLANES];
  memset(nref, 0, sizeof(nref));
  memset(nfine, 0, sizeof(nfine));
  size_t npx = (size_t)w * (size_t)h;
  uint32_t *copy = malloc(sizeof(uint32_t) * 2 * npx);
  uint8_t *done = calloc(npx, 1);
  int rc = copy && done ? planes_copy(nref, r->nplanes, rw, rh, ref) : TS_ENOMEM;
  if (rc == 0) rc = planes_copy(nfine, r->nplanes, w, h, NULL);
  if (rc != 0) {
    free(copy);
    free(done);
    planes_free(nref);
    planes_free(nfine);
    return ts_error(err, TS_ENOMEM, "out of memory for a %dx%d query image", w, h);
  }
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      int sx, sy;
      ts_copy_predict(r->copy, r->w, r->h, w, h, rw, rh, x, y, &sx, &sy);
      size_t o = (size_t)y * (size_t)w + (size_t)x;
      for (int k = 0; k < r->nplanes; k++) nfine[k].px[o] = ts_plane_at(&nref[k], sx, sy);
      copy[2 * o] = (uint32_t)sx;
      copy[2 * o + 1] = (uint32_t)sy;
    }
  planes_free(r->coarse);
  planes_free(r->ref);
  memcpy(r->coarse, r->fine, sizeof(r->fine));
  memcpy(r->fine, nfine, sizeof(nfine));
  memcpy(r->ref, nref, sizeof(nref));
  free(r->copy);
  free(r->done);
  r->copy = copy;
  r->done = done;
  r->w = w;
  r->h = h;
  r->seq = 0;
  point_planes(r);
  return 0;
}

/* The block at canvas pixel dst, clipped at the canvas edge. */
static void block_at(const ts_replica *r, uint32_t dst, int *x, int *y, int *bw, int *bh) {
  *x = (int)(dst % (uint32_t)r->w);
  *y = (int)(dst / (uint32_t)r->w);
  *bw = r->block < r->w - *x ? r->block : r->w - *x;
  *bh = r->block < r->h - *y ? r->block : r->h - *y;
}

static int check_place(const ts_replica *r, const ts_place *p, char *err) {
  const ts_plane *ref = &r->ref[0];
  if (p->dst >= (uint32_t)r->w * (uint32_t)r->h)
    return ts_error(err, TS_EINVAL, "a block placed at pixel %u of a %dx%d image", p->dst, r->w, r->h);
  int x, y, bw, bh;
  block_at(r, p->dst, &x, &y, &bw, &bh);
  uint32_t sx = p->src % (uint32_t)ref->w, sy = p->src / (uint32_t)ref->w;
  if (sy + (uint32_t)bh > (uint32_t)ref->h || sx + (uint32_t)bw > (uint32_t)ref->w)
    return ts_error(err, TS_EINVAL, "a %dx%d block copied from (%u, %u) of the %dx%d reference", bw, bh, sx, sy,
                    ref->w, ref->h);
  if (r->copy == NULL && r->done[p->dst] == TS_DONE_PLACED)
    return ts_error(err, TS_EINVAL, "a block placed twice at pixel %u of an image that keeps no copy map", p->dst);
  return 0;
}

static void place_one(ts_replica *r, const ts_place *p, ts_commit *commits, uint32_t *nc) {
  int x, y, bw, bh;
  block_at(r, p->dst, &x, &y, &bw, &bh);
  int sx = (int)(p->src % (uint32_t)r->ref[0].w), sy = (int)(p->src / (uint32_t)r->ref[0].w);
  if (r->copy != NULL && r->done[p->dst] == TS_DONE_PLACED) /* a sweep replaces a counted copy */
    commits[(*nc)++] = (ts_commit){(int32_t)r->copy[2 * p->dst], (int32_t)r->copy[2 * p->dst + 1], (uint16_t)bw,
                                   (uint16_t)bh, -1};
  commits[(*nc)++] = (ts_commit){sx, sy, (uint16_t)bw, (uint16_t)bh, 1};
  for (int dy = 0; dy < bh; dy++)
    for (int dx = 0; dx < bw; dx++) {
      size_t o = (size_t)(y + dy) * (size_t)r->w + (size_t)(x + dx);
      if (r->done[o] >= TS_DONE_FIXED) continue; /* given, or not this one's to fill */
      for (int k = 0; k < r->nplanes; k++) r->fine[k].px[o] = ts_plane_at(&r->ref[k], sx + dx, sy + dy);
      if (r->copy != NULL) {
        r->copy[2 * o] = (uint32_t)(sx + dx);
        r->copy[2 * o + 1] = (uint32_t)(sy + dy);
      }
      r->done[o] = TS_DONE_PLACED;
    }
}

int ts_replica_place(ts_replica *r, const ts_place *p, uint32_t n, ts_commit *commits, uint32_t *ncommits,
                     char *err) {
  *ncommits = 0;
  if (n > 0 && r->block == 0) return ts_error(err, TS_EINVAL, "blocks placed on a query image that takes none");
  for (uint32_t i = 0; i < n; i++) {
    int rc = check_place(r, &p[i], err);
    if (rc != 0) return rc;
  }
  for (uint32_t i = 0; i < n; i++) place_one(r, &p[i], commits, ncommits);
  return 0;
}

int ts_replica_queries(const ts_replica *r, const ts_window *w, const uint32_t *pos, uint32_t n, int masked,
                       uint8_t *vec, uint8_t *mask, char *err) {
  if (w->spec.nplanes[TS_SRC_FINE] > r->nplanes ||
      (ts_window_has_coarse(w) && (w->spec.nplanes[TS_SRC_COARSE] > r->nplanes || r->coarse[0].px == NULL)))
    return ts_error(err, TS_EINVAL, "a window of %d fine and %d coarse planes on a query image of %d planes%s",
                    w->spec.nplanes[TS_SRC_FINE], w->spec.nplanes[TS_SRC_COARSE], r->nplanes,
                    r->coarse[0].px ? "" : " without coarse planes");
  if (masked && w->spec.known == NULL) return ts_error(err, TS_EINVAL, "masked queries with a window that has no known offsets");
  uint32_t npx = (uint32_t)r->w * (uint32_t)r->h, vb = ts_window_bytes(w);
  for (uint32_t i = 0; i < n; i++)
    if (pos[i] >= npx) return ts_error(err, TS_EINVAL, "query at pixel %u of a %dx%d image", pos[i], r->w, r->h);
  for (uint32_t i = 0; i < n; i++) {
    int x = (int)(pos[i] % (uint32_t)r->w), y = (int)(pos[i] / (uint32_t)r->w);
    ts_vec_query(w, &r->planes, !r->bounded, x, y, vec + (size_t)i * vb);
    if (masked) ts_vec_mask(w, r->done, r->w, r->h, !r->bounded, x, y, mask + (size_t)i * vb);
  }
  return 0;
}

void ts_query_scratch_free(ts_query_scratch *s) {
  free(s->vec);
  free(s->mask);
  memset(s, 0, sizeof(*s));
}

int ts_query_vectors(ts_query_scratch *s, const ts_replica *r, const ts_window *w, const ts_query_batch *b,
                     ts_vec_batch *out, char *err) {
  size_t bytes = (size_t)b->nq * ts_window_bytes(w);
  if (bytes > s->cap) {
    ts_query_scratch_free(s);
    s->vec = malloc(bytes);
    s->mask = malloc(bytes);
    if (s->vec == NULL || s->mask == NULL) {
      ts_query_scratch_free(s);
      return ts_error(err, TS_ENOMEM, "out of memory for a batch of %u queries", b->nq);
    }
    s->cap = bytes;
  }
  int rc = ts_replica_queries(r, w, b->pos, b->nq, b->masked, s->vec, s->mask, err);
  *out = (ts_vec_batch){b->nq, s->vec, b->masked ? s->mask : NULL, b->klass, b->usage_k};
  return rc;
}

int ts_replica_slice_rows(const ts_replica *r, ts_slice_desc *m, char *err) {
  int n = m->win.nplanes[TS_SRC_FINE];
  if (r == NULL || r->block == 0)
    return ts_error(err, TS_EINVAL, "slice %u takes its rows from query image %u, which holds no reference here", m->set,
                    m->image);
  if (r->ref[0].w != m->w || r->ref[0].h != m->h || n > r->nplanes)
    return ts_error(err, TS_EINVAL, "slice %u reads %d planes of %dx%d, query image %u's reference is %d of %dx%d",
                    m->set, n, m->w, m->h, m->image, r->nplanes, r->ref[0].w, r->ref[0].h);
  size_t w = (size_t)m->w;
  for (int p = 0; p < n; p++)
    m->fine[p] = (ts_slice_rows){r->ref[p].px + (size_t)m->fy0 * w, r->ref[p].px + (size_t)m->kfy1 * w};
  if (ts_slice_fine_sum(m) != m->fine_sum)
    return ts_error(err, TS_EINVAL, "slice %u: query image %u holds other reference rows than the coordinator's "
                    "(another level)", m->set, m->image);
  return 0;
}
