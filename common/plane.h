/* plane.h - 8-bit single-channel planes and Gaussian pyramids of them.
 *
 * The synthesis searches on 8-bit feature planes (luminance, or each colour
 * channel with --rgb-search); the real pixels of any type are gathered
 * through the copy map at the end (seed 002 §3.8). */
#ifndef TS_PLANE_H
#define TS_PLANE_H

#include <stdint.h>

typedef struct {
  int w, h;
  uint8_t *px; /* w*h bytes, row-major */
} ts_plane;

int ts_plane_alloc(ts_plane *p, int w, int h);
void ts_plane_free(ts_plane *p);

static inline uint8_t ts_plane_at(const ts_plane *p, int x, int y) {
  return p->px[(long)y * p->w + x];
}

/* Torus read (seed 002 eq. 3.1): coordinates taken modulo the plane size. */
static inline uint8_t ts_plane_wrap(const ts_plane *p, int x, int y) {
  x %= p->w;
  y %= p->h;
  if (x < 0) x += p->w;
  if (y < 0) y += p->h;
  return p->px[(long)y * p->w + x];
}

/* Parity control (seed 002 §3.3.3): a block at (x, y) copies only from
 * reference blocks of the same (x & 1, y & 1), its class. ts_plane_parity
 * makes a w x h plane of every pixel's class (the label plane of anchors
 * under parity control): 0, or TS_ENOMEM. */
static inline int ts_parity_class(int x, int y) { return (x & 1) | (y & 1) << 1; }
int ts_plane_parity(ts_plane *p, int w, int h);

/* An index mirrored into [0, n) without repeating the edge sample
 * (-1 -> 1, n -> n - 2): how filters read past a plane's border. */
static inline int ts_plane_mirror(int i, int n) {
  if (n == 1) return 0;
  while (i < 0 || i >= n) {
    if (i < 0) i = -i;
    if (i >= n) i = 2 * (n - 1) - i;
  }
  return i;
}

/* One Gaussian reduction step (seed 002 eqs. 2.1-2.3): the separable kernel
 * g = (0.05, 0.25, 0.4, 0.25, 0.05) = (1, 5, 8, 5, 1) / 20, evaluated at
 * (2x, 2y) with mirrored borders, in exact integer arithmetic rounded to
 * nearest. dst gets floor(w/2) x floor(h/2) (an odd last row or column is
 * lost, as in the seed). Source must be at least 2x2. */
int ts_plane_reduce(const ts_plane *src, ts_plane *dst);

/* The masked reduction of seed 002 §3.3.1 (normalised convolution): the
 * kernel of ts_plane_reduce over the taps where mask is non-zero only,
 * renormalised by their weight, so an undefined area (a hole, an area not
 * synthesised yet) neither darkens nor spreads into its edge. dst is
 * ceil(w/2) x ceil(h/2) with ceil_size, else floor; a pixel without a
 * defined tap is 0. mask has src's size. */
int ts_plane_reduce_masked(const ts_plane *src, const ts_plane *mask, int ceil_size, ts_plane *dst);

/* A mask one level down: non-zero where every pixel of the 2 x 2 cell
 * below (clipped at the edge) is non-zero. dst has the size
 * ts_plane_reduce_masked gives with ceil_size. */
int ts_plane_reduce_all(const ts_plane *mask, int ceil_size, ts_plane *dst);

/* levels[0] = a copy of base, levels[l+1] = reduce(levels[l]). */
int ts_pyramid_build(const ts_plane *base, int nlevels, ts_plane *levels);
void ts_pyramid_free(ts_plane *levels, int nlevels);

#endif
