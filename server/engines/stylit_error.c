/* stylit_error.c - the per-pixel error of a finished stylization
 * (stylit.h): how well each output pixel's patch matches the exemplar
 * patch the NNF gave it, measured with the engine's own vectors.
 *
 * Why a map and not only the energy: `texsyn video` blends two chains of
 * stylized frames per pixel by the error each chain piled up along the
 * flow (Jamriška et al. 2019), which needs the error where it is, frame by
 * frame, and from the job that made the frame (the NNF it settled on, not
 * a new search as the energy makes). Integer distances (l1.h's weighted
 * L1, 64-bit) divided once by the window's one-grey-level distance: the
 * same float for the same job on any machine. */
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "stylit.h"

/* The weighted L1 distance of two vectors of the window's layout. */
static uint64_t weighted_sad(const ts_window *win, const uint8_t *a, const uint8_t *b) {
  uint64_t d = 0;
  uint32_t c0 = 0;
  for (int p = 0; p < win->spec.nparts; p++) {
    uint64_t sad = 0;
    for (uint32_t i = c0 * TS_L1_CHUNK; i < win->part_end[p] * TS_L1_CHUNK; i++) sad += (uint64_t)abs(a[i] - b[i]);
    d += sad * win->spec.part[p].weight;
    c0 = win->part_end[p];
  }
  return d;
}

int ts_stylit_error_map(const ts_stylit_params *p, const ts_image *const *in, const ts_stylit_result *res,
                        float *out, char *err) {
  ts_stylit_planes pl;
  ts_window win = {0};
  ts_plane pad[TS_WIN_MAX_PLANES] = {0};
  int tw = res->image.width, th = res->image.height, r = p->patch / 2;
  if (ts_stylit_planes_init(&pl, p, in) != 0) return ts_error(err, TS_ENOMEM, "out of memory for the inputs");
  int rc = 0;
  for (int c = 0; rc == 0 && c < pl.nstyle; c++) {
    if (ts_plane_alloc(&pl.tgt[c], tw, th) != 0) rc = ts_error(err, TS_ENOMEM, "out of memory");
    else ts_image_channel8(&res->image, c, pl.tgt[c].px);
  }
  if (rc == 0) rc = ts_stylit_window(&win, p, &pl, err);
  const ts_plane *t[TS_WIN_MAX_PLANES];
  for (int k = 0; k < pl.nplanes; k++) t[k] = &pl.tgt[k];
  if (rc == 0 && ts_stylit_pad(t, pl.nplanes, r, pad) != 0) rc = ts_error(err, TS_ENOMEM, "out of memory");
  uint8_t *q = rc == 0 ? malloc(ts_window_bytes(&win)) : NULL, *s = rc == 0 ? malloc(ts_window_bytes(&win)) : NULL;
  if (rc == 0 && (q == NULL || s == NULL)) rc = ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) {
    ts_levelplanes src = {{NULL}, {NULL}}, tgt = {{NULL}, {NULL}};
    for (int k = 0; k < pl.nplanes; k++) {
      src.fine[k] = &pl.src[k];
      tgt.fine[k] = &pad[k];
    }
    memset(q, 0, ts_window_bytes(&win));
    memset(s, 0, ts_window_bytes(&win));
    double unit = (double)ts_window_unit_distance(&win);
    for (int y = 0; y < th; y++)
      for (int x = 0; x < tw; x++) {
        size_t i = (size_t)y * (size_t)tw + (size_t)x;
        ts_vec_query(&win, &tgt, 0, x, y, q);
        ts_vec_ref(&win, &src, (int)res->nnf[2 * i] - r, (int)res->nnf[2 * i + 1] - r, s);
        out[i] = (float)((double)weighted_sad(&win, q, s) / unit);
      }
  }
  free(q);
  free(s);
  for (int k = 0; k < TS_WIN_MAX_PLANES; k++) ts_plane_free(&pad[k]);
  ts_window_free(&win);
  ts_stylit_planes_free(&pl);
  return rc;
}
