/* repetition.c - see repetition.h.
 *
 * Patches are labelled with a union-find over the pixels (path halving,
 * union by index: the smaller root wins, so labels do not depend on the
 * order of unions), then sized; a counter per reference pixel (and source
 * id) counts the large patches' uses. Memory: 8 bytes an image pixel and
 * 2 a reference pixel; one pass each. */
#include "repetition.h"

#include <stdlib.h>

#include "error.h"

static uint32_t root(uint32_t *parent, uint32_t i) {
  while (parent[i] != i) {
    parent[i] = parent[parent[i]];
    i = parent[i];
  }
  return i;
}

static void join(uint32_t *parent, uint32_t a, uint32_t b) {
  a = root(parent, a);
  b = root(parent, b);
  if (a < b) parent[b] = a;
  else if (b < a) parent[a] = b;
}

/* Pixels i and j (neighbours) are one piece: both have sources, in one
 * reference, at the same offset. */
static int same_piece(const uint32_t *copy, const uint8_t *id, size_t i, size_t j, int64_t dx, int64_t dy) {
  if (copy[2 * i] == UINT32_MAX || copy[2 * j] == UINT32_MAX) return 0;
  if (id != NULL && id[i] != id[j]) return 0;
  return (int64_t)copy[2 * j] - (int64_t)copy[2 * i] == dx && (int64_t)copy[2 * j + 1] - (int64_t)copy[2 * i + 1] == dy;
}

static void label(const uint32_t *copy, const uint8_t *id, int w, int h, uint32_t *parent) {
  size_t n = (size_t)w * (size_t)h;
  for (size_t i = 0; i < n; i++) parent[i] = (uint32_t)i;
  for (int y = 0; y < h; y++)
    for (int x = 0; x < w; x++) {
      size_t i = (size_t)y * (size_t)w + (size_t)x;
      if (x + 1 < w && same_piece(copy, id, i, i + 1, 1, 0)) join(parent, (uint32_t)i, (uint32_t)(i + 1));
      if (y + 1 < h && same_piece(copy, id, i, i + (size_t)w, 0, 1)) join(parent, (uint32_t)i, (uint32_t)(i + (size_t)w));
    }
}

static int check(const uint32_t *copy, const uint8_t *id, int nsrc, size_t n, int rw, int rh, char *err) {
  for (size_t i = 0; i < n; i++) {
    if (copy[2 * i] == UINT32_MAX) continue;
    if (copy[2 * i] >= (uint32_t)rw || copy[2 * i + 1] >= (uint32_t)rh || (id != NULL && id[i] >= nsrc))
      return ts_error(err, TS_EINVAL, "copy map pixel %zu: source (%u, %u) of reference %d outside %dx%d (of %d)", i,
                      copy[2 * i], copy[2 * i + 1], id != NULL ? id[i] : 0, rw, rh, nsrc);
  }
  return 0;
}

int ts_repetition_score(const uint32_t *copy, const uint8_t *src_id, int nsrc, int w, int h, int rw, int rh,
                        int side, ts_repetition *out, char *err) {
  *out = (ts_repetition){.side = side};
  size_t n = (size_t)w * (size_t)h, nref = (size_t)rw * (size_t)rh * (size_t)(src_id != NULL ? nsrc : 1);
  if (w < 1 || h < 1 || rw < 1 || rh < 1 || side < 1 || n >= UINT32_MAX || (src_id != NULL && nsrc < 1))
    return ts_error(err, TS_EINVAL, "a repetition score of %dx%d pixels from %dx%d references: bad sizes", w, h, rw, rh);
  int rc = check(copy, src_id, nsrc, n, rw, rh, err);
  if (rc != 0) return rc;
  uint32_t *parent = malloc(n * sizeof(uint32_t)), *size = calloc(n, sizeof(uint32_t));
  uint16_t *uses = calloc(nref, sizeof(uint16_t));
  if (parent == NULL || size == NULL || uses == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory for a repetition score");
  if (rc == 0) {
    label(copy, src_id, w, h, parent);
    for (size_t i = 0; i < n; i++) {
      if (copy[2 * i] == UINT32_MAX) continue;
      out->pixels++;
      uint32_t r = root(parent, (uint32_t)i);
      parent[i] = r; /* roots are the least index of their patch: set before i */
      out->patches += r == i;
      size[r]++;
    }
    uint64_t large = (uint64_t)side * (uint64_t)side;
    for (int pass = 0; pass < 2; pass++)
      for (size_t i = 0; i < n; i++) {
        if (copy[2 * i] == UINT32_MAX || size[parent[i]] < large) continue;
        size_t s = ((size_t)(src_id != NULL ? src_id[i] : 0) * (size_t)rh + copy[2 * i + 1]) * (size_t)rw + copy[2 * i];
        if (pass == 0) {
          uses[s] += uses[s] < UINT16_MAX;
          out->large++;
          out->large_patches += parent[i] == i;
        } else {
          out->repeated += uses[s] >= 2;
        }
      }
    out->share = out->pixels > 0 ? (double)out->repeated / (double)out->pixels : 0.0;
  }
  free(parent);
  free(size);
  free(uses);
  return rc;
}
