/* window.c - see window.h. */
#include "window.h"

#include <stdlib.h>
#include <string.h>

#include "error.h"

static const char *const source_name[TS_NSRC] = {"fine", "coarse"};

static int box_ok(const ts_box *b) {
  return b->dx0 < b->dx1 && b->dy0 < b->dy1 && b->dx0 >= -TS_WIN_MAX_REACH && b->dy0 >= -TS_WIN_MAX_REACH &&
         b->dx1 <= TS_WIN_MAX_REACH && b->dy1 <= TS_WIN_MAX_REACH;
}

static int check_source(const ts_window_spec *s, int src, char *err) {
  const char *name = source_name[src];
  if (s->nplanes[src] < 0 || s->nplanes[src] > TS_WIN_MAX_PLANES)
    return ts_error(err, TS_EINVAL, "%d %s planes: need 0..%d", s->nplanes[src], name, TS_WIN_MAX_PLANES);
  if (s->nplanes[src] == 0) return 0;
  if (s->noff[src] < 1 || s->noff[src] > TS_WIN_MAX_OFFSETS)
    return ts_error(err, TS_EINVAL, "%d %s offsets: need 1..%d", s->noff[src], name, TS_WIN_MAX_OFFSETS);
  const ts_box *b = &s->extent[src];
  if (!box_ok(b))
    return ts_error(err, TS_EINVAL, "%s extent [%d, %d) x [%d, %d): need a non-empty box within +-%d", name, b->dx0,
                    b->dx1, b->dy0, b->dy1, TS_WIN_MAX_REACH);
  for (int k = 0; k < s->noff[src]; k++) {
    int dx = s->dx[src][k], dy = s->dy[src][k];
    if (dx < b->dx0 || dx >= b->dx1 || dy < b->dy0 || dy >= b->dy1)
      return ts_error(err, TS_EINVAL, "%s offset (%d, %d) lies outside its extent [%d, %d) x [%d, %d)", name, dx, dy,
                      b->dx0, b->dx1, b->dy0, b->dy1);
  }
  return 0;
}

static int check_spec(const ts_window_spec *s, char *err) {
  if (s->nplanes[TS_SRC_FINE] < 1) return ts_error(err, TS_EINVAL, "a window needs at least one fine plane");
  for (int src = 0; src < TS_NSRC; src++) {
    int rc = check_source(s, src, err);
    if (rc != 0) return rc;
  }
  if (s->centre < 0 || s->centre > TS_WIN_MAX_REACH)
    return ts_error(err, TS_EINVAL, "coarse centre shift %d: need 0..%d", s->centre, TS_WIN_MAX_REACH);
  if (s->block < 1 || s->block > TS_WIN_MAX_REACH)
    return ts_error(err, TS_EINVAL, "copied block side %d: need 1..%d", s->block, TS_WIN_MAX_REACH);
  if (s->nparts < 1 || s->nparts > TS_L1_MAX_PARTS)
    return ts_error(err, TS_EINVAL, "%d weighted parts: need 1..%d", s->nparts, TS_L1_MAX_PARTS);
  for (int p = 0; p < s->nparts; p++) {
    const ts_part *pt = &s->part[p];
    if (pt->source >= TS_NSRC || pt->nplanes < 1 || pt->plane0 + pt->nplanes > s->nplanes[pt->source])
      return ts_error(err, TS_EINVAL, "part %d: planes %d..%d of source %d, which has %d", p, pt->plane0,
                      pt->plane0 + pt->nplanes - 1, pt->source,
                      pt->source < TS_NSRC ? s->nplanes[pt->source] : 0);
  }
  return 0;
}

/* Chunk ends of the parts; refuses vectors longer than the kernels take. */
static int lay_out(ts_window *w, char *err) {
  const ts_window_spec *s = &w->spec;
  uint64_t chunks = 0;
  for (int p = 0; p < s->nparts; p++) {
    uint64_t bytes = (uint64_t)s->part[p].nplanes * (uint64_t)s->noff[s->part[p].source];
    chunks += (bytes + TS_L1_CHUNK - 1) / TS_L1_CHUNK;
    if (chunks > TS_L1_MAX_CHUNKS)
      return ts_error(err, TS_EINVAL, "vectors of more than %d bytes (the window's parts are too long)",
                      TS_L1_MAX_CHUNKS * TS_L1_CHUNK);
    w->part_end[p] = (uint32_t)chunks;
  }
  w->nchunks = (uint32_t)chunks;
  return 0;
}

int ts_window_init(ts_window *w, const ts_window_spec *spec, char *err) {
  memset(w, 0, sizeof(*w));
  int rc = check_spec(spec, err);
  if (rc != 0) return rc;
  w->spec = *spec;
  size_t total = 0;
  for (int src = 0; src < TS_NSRC; src++)
    if (spec->nplanes[src] > 0) total += 2 * (size_t)spec->noff[src];
  size_t nknown = spec->known ? (size_t)spec->noff[TS_SRC_FINE] : 0;
  w->off = malloc(sizeof(int16_t) * total + nknown + 1);
  if (w->off == NULL) return ts_error(err, TS_ENOMEM, "out of memory for a window");
  int16_t *o = w->off;
  for (int src = 0; src < TS_NSRC; src++) {
    if (spec->nplanes[src] == 0) {
      w->spec.noff[src] = 0;
      w->spec.dx[src] = w->spec.dy[src] = NULL;
      continue;
    }
    size_t n = (size_t)spec->noff[src];
    memcpy(o, spec->dx[src], n * sizeof(int16_t));
    memcpy(o + n, spec->dy[src], n * sizeof(int16_t));
    w->spec.dx[src] = o;
    w->spec.dy[src] = o + n;
    o += 2 * n;
  }
  if (nknown > 0) {
    uint8_t *known = (uint8_t *)o;
    for (size_t k = 0; k < nknown; k++) known[k] = spec->known[k] != 0;
    w->spec.known = known;
  }
  rc = lay_out(w, err);
  if (rc != 0) ts_window_free(w);
  return rc;
}

void ts_window_free(ts_window *w) {
  free(w->off);
  w->off = NULL;
}

int ts_window_weigh(const ts_window *w, ts_l1_set *set, char *err) {
  uint64_t weight[TS_L1_MAX_PARTS];
  for (int p = 0; p < w->spec.nparts; p++) weight[p] = w->spec.part[p].weight;
  return ts_l1_set_weigh(set, (uint32_t)w->spec.nparts, w->part_end, weight, err);
}

/* Writes part p at out + *n: its planes' pixels at the source's offsets
 * around (x, y), read on the torus if wrap, then zeros to the part's chunk
 * end. Always inlined with a constant wrap, so the plain reads carry no
 * modulo. */
static inline __attribute__((always_inline)) void put_part(const ts_window *w, int p,
                                                           const ts_plane *const *planes, int x, int y,
                                                           const int wrap, uint8_t *out, uint32_t *n) {
  const ts_part *pt = &w->spec.part[p];
  const int16_t *dx = w->spec.dx[pt->source], *dy = w->spec.dy[pt->source];
  int no = w->spec.noff[pt->source];
  uint32_t k = *n;
  for (int q = pt->plane0; q < pt->plane0 + pt->nplanes; q++) {
    const ts_plane *pl = planes[q];
    for (int i = 0; i < no; i++)
      out[k++] = wrap ? ts_plane_wrap(pl, x + dx[i], y + dy[i]) : ts_plane_at(pl, x + dx[i], y + dy[i]);
  }
  while (k < w->part_end[p] * TS_L1_CHUNK) out[k++] = 0;
  *n = k;
}

void ts_vec_ref(const ts_window *w, const ts_levelplanes *ref, int x, int y, uint8_t *out) {
  int cx = (x + w->spec.centre) / 2, cy = (y + w->spec.centre) / 2;
  uint32_t n = 0;
  for (int p = 0; p < w->spec.nparts; p++) {
    if (w->spec.part[p].source == TS_SRC_FINE) put_part(w, p, ref->fine, x, y, 0, out, &n);
    else put_part(w, p, ref->coarse, cx, cy, 0, out, &n);
  }
}

/* The coarse pixel under the block centre of fine (x, y): x/2 for even
 * sizes, and a consistent torus mapping for any size; clamped to the
 * coarse plane on a bounded image, whose blocks may overhang its edge. */
static void coarse_centre(const ts_window *w, const ts_plane *f, const ts_plane *c0, int x, int y, int torus,
                          int *cx, int *cy) {
  long fx = x + w->spec.centre, fy = y + w->spec.centre;
  if (torus) {
    fx %= f->w;
    fy %= f->h;
  } else {
    fx = fx < f->w ? fx : f->w - 1;
    fy = fy < f->h ? fy : f->h - 1;
  }
  *cx = (int)(fx * c0->w / f->w);
  *cy = (int)(fy * c0->h / f->h);
}

/* Part p of a bounded image: offsets outside the planes read 0 (the mask
 * never counts them), coarse ones the nearest edge pixel. */
static void put_part_bounded(const ts_window *w, int p, const ts_plane *const *planes, int x, int y, int coarse,
                             uint8_t *out, uint32_t *n) {
  const ts_part *pt = &w->spec.part[p];
  const int16_t *dx = w->spec.dx[pt->source], *dy = w->spec.dy[pt->source];
  int no = w->spec.noff[pt->source];
  uint32_t k = *n;
  for (int q = pt->plane0; q < pt->plane0 + pt->nplanes; q++) {
    const ts_plane *pl = planes[q];
    for (int i = 0; i < no; i++) {
      int px = x + dx[i], py = y + dy[i];
      int in = px >= 0 && py >= 0 && px < pl->w && py < pl->h;
      if (coarse) {
        px = px < 0 ? 0 : px >= pl->w ? pl->w - 1 : px;
        py = py < 0 ? 0 : py >= pl->h ? pl->h - 1 : py;
        in = 1;
      }
      out[k++] = in ? ts_plane_at(pl, px, py) : 0;
    }
  }
  while (k < w->part_end[p] * TS_L1_CHUNK) out[k++] = 0;
  *n = k;
}

void ts_vec_query(const ts_window *w, const ts_levelplanes *canvas, int torus, int x, int y, uint8_t *out) {
  const ts_plane *f = canvas->fine[0];
  const ts_box *e = &w->spec.extent[TS_SRC_FINE];
  /* Most windows lie inside: they skip the modulo and the bounds. */
  int inside = x + e->dx0 >= 0 && y + e->dy0 >= 0 && x + e->dx1 <= f->w && y + e->dy1 <= f->h;
  int cx = 0, cy = 0;
  if (ts_window_has_coarse(w)) coarse_centre(w, f, canvas->coarse[0], x, y, torus, &cx, &cy);
  uint32_t n = 0;
  for (int p = 0; p < w->spec.nparts; p++) {
    int coarse = w->spec.part[p].source == TS_SRC_COARSE;
    if (coarse && torus) put_part(w, p, canvas->coarse, cx, cy, 1, out, &n);
    else if (coarse) put_part_bounded(w, p, canvas->coarse, cx, cy, 1, out, &n);
    else if (inside) put_part(w, p, canvas->fine, x, y, 0, out, &n);
    else if (torus) put_part(w, p, canvas->fine, x, y, 1, out, &n);
    else put_part_bounded(w, p, canvas->fine, x, y, 0, out, &n);
  }
}

int ts_vec_mask(const ts_window *w, const uint8_t *done, int cw, int ch, int torus, int x, int y, uint8_t *mask) {
  const ts_window_spec *s = &w->spec;
  int nf = s->noff[TS_SRC_FINE], bw = s->block < cw - x ? s->block : cw - x, bh = s->block < ch - y ? s->block : ch - y;
  uint8_t fine[TS_WIN_MAX_OFFSETS];
  int differs = 0;
  for (int k = 0; k < nf; k++) {
    int dx = s->dx[TS_SRC_FINE][k], dy = s->dy[TS_SRC_FINE][k];
    int written = dx >= 0 && dx < bw && dy >= 0 && dy < bh;
    int px = x + dx, py = y + dy, state = TS_DONE_CLOSED;
    if (torus) state = done[(size_t)((py % ch + ch) % ch) * (size_t)cw + (size_t)((px % cw + cw) % cw)];
    else if (px >= 0 && py >= 0 && px < cw && py < ch) state = done[(size_t)py * (size_t)cw + (size_t)px];
    int known = s->known[k] || state == TS_DONE_FIXED || (!written && state == TS_DONE_PLACED);
    differs |= known != s->known[k];
    fine[k] = known ? 0xFF : 0x00;
  }
  uint32_t n = 0;
  for (int p = 0; p < s->nparts; p++) {
    const ts_part *pt = &s->part[p];
    for (int q = 0; pt->source == TS_SRC_FINE && q < pt->nplanes; q++, n += (uint32_t)nf) memcpy(mask + n, fine, (size_t)nf);
    memset(mask + n, 0xFF, w->part_end[p] * TS_L1_CHUNK - n); /* coarse parts and padding: always used */
    n = w->part_end[p] * TS_L1_CHUNK;
  }
  return differs;
}

uint64_t ts_window_unit_distance(const ts_window *w) {
  uint64_t d = 0;
  for (int p = 0; p < w->spec.nparts; p++) {
    const ts_part *pt = &w->spec.part[p];
    d += (uint64_t)pt->weight * (uint64_t)pt->nplanes * (uint64_t)w->spec.noff[pt->source];
  }
  return d;
}
