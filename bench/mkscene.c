/* mkscene.c - synthetic aerial scenes for the tests and benchmarks of
 * aerial synthesis (seed 002 §5.1): a land-use class map and a road
 * raster of the same size, made from a seed in seconds at any size from
 * 64x64 to 16384x16384 (to 65536x65536 as GIS files, --gis).
 *
 *   PREFIX-classes.png  8-bit grey, each pixel a class id 1..K:
 *                       1 forest, 2 water, 3 town, 4 sand, 5 grassland,
 *                       6 arable, 7 industrial, 8 wetland
 *   PREFIX-roads.png    8-bit grey: 0 no line, 255 road (3..9 px wide),
 *                       128 path (2 px wide)
 *
 * The class ids are those of bench/aerial_refs.sh's catalogue.
 *
 * How the map is made. The land classes (forest, sand, grassland, arable,
 * wetland) fill the cells of a jittered-grid Voronoi partition, each class
 * in a share of the cells set by its weight, dealt out shuffled so every
 * one is there. Settlements (town, industrial) are clusters of discs,
 * water one meandering river band and a few lakes of overlapping discs.
 * Every test is made on domain-warped coordinates (the pixel moved by
 * three octaves of value noise), which turns straight Voronoi edges and
 * round discs into smooth, irregular boundaries. All sizes scale with the
 * image: the cell is sqrt(W*H)/16 across, so an 8192x8192 map has ~256
 * cells of ~512 px, merging into regions of a few hundred to a few
 * thousand pixels. Roads and paths are drawn at fixed widths in pixels
 * (they are ground widths, not map features that scale).
 *
 * Same options, same bytes: everything random comes from the seed through
 * common/rng.h and integer hashing, and the floating point uses only
 * +, -, *, /, floor and sqrt (exact in IEEE arithmetic), so no libm
 * difference can change a pixel.
 *
 * GIS files (--gis, issue 28): the same map as a georeferenced tiled
 * GeoTIFF, PREFIX-classes.tif, in --crs (default EPSG:32632, UTM zone 32N)
 * at --pixel-size metres (default 0.25), made and written 512 rows at a
 * time through the GIS library (common/gis.h), so a 32768x32768 map takes
 * a strip of 16 MiB and GDAL's cache, not 1 GiB; the roads and paths, the
 * same polylines the PNG raster draws, as a GeoJSON layer in that CRS,
 * PREFIX-roads.geojson, each line with its kind ("road", "path") and
 * width in metres; and PREFIX-lines.json, line rules (gis.h's JSON form)
 * that draw them as the PNG does: roads 255 over paths 128. The PNG mode
 * is unchanged, byte for byte.
 *
 * Usage: mkscene -o PREFIX [--size N|WxH] [--seed S] [--classes K]
 *                [--gis [--crs EPSG:N] [--pixel-size M]]
 * (defaults: 1024, 1, 4). Prints each class's share of the map and the
 * roads' and paths' share of the raster (with --gis, their counts). Exit
 * status 2 for bad options, 1 for a failure to write. */
#include <getopt.h>
#include <limits.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "error.h"
#include "gis.h"
#include "image.h"
#include "rng.h"
#include "util.h"

#define MIN_SIDE 64
#define MAX_SIDE 16384
#define MAX_GIS_SIDE 65536 /* --gis: made by strips, never whole */
#define CELLS_ACROSS 16  /* Voronoi cells along sqrt(W*H) */
#define WARP 0.45        /* warp amplitude, in cells */
#define ROAD 255
#define PATH 128

typedef enum { LAND, WATER, SETTLEMENT } role;

/* The classes by id (index + 1); weight: share of the Voronoi cells. */
static const struct {
  const char *name;
  role role;
  double weight;
} classes[] = {
    {"forest", LAND, 3.0},    {"water", WATER, 0},         {"town", SETTLEMENT, 0}, {"sand", LAND, 1.5},
    {"grassland", LAND, 2.0}, {"arable", LAND, 2.0},       {"industrial", SETTLEMENT, 0},
    {"wetland", LAND, 1.0},
};
#define MAX_CLASSES ((int)(sizeof(classes) / sizeof(classes[0])))

/* One disc of a settlement or lake, in warped coordinates. */
typedef struct {
  double x, y, r;
  uint8_t id;
} disc;

typedef struct {
  int w, h, nclass;
  uint64_t seed;
  double cell;       /* Voronoi cell size, px */
  /* Voronoi seeds and their classes, (nx + 2) x (ny + 2) cells: one cell
   * of margin around the image, since warped points may leave it. */
  int nx, ny;
  double *sx, *sy;
  uint8_t *cls;
  /* The warp, sampled every step px and interpolated between. */
  int step, gw, gh;
  double *wx, *wy;
  /* Settlements and lakes (drawn in this order), the river. */
  disc *discs;
  int ndisc, cap;
  int has_river, river_vertical;
  double *river_c, *river_hw; /* centre and half width along the river */
} scene;

/* --- noise ------------------------------------------------------------------ */

static uint64_t mix64(uint64_t x) { /* splitmix64's finaliser */
  x ^= x >> 30;
  x *= 0xbf58476d1ce4e5b9ull;
  x ^= x >> 27;
  x *= 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}

/* A random value in [-1, 1) at lattice point (ix, iy) of noise key. */
static double lattice(uint64_t key, int64_t ix, int64_t iy) {
  uint64_t h = mix64(key ^ mix64((uint64_t)ix * 0x9e3779b97f4a7c15ull ^ (uint64_t)iy * 0xc2b2ae3d27d4eb4full));
  return (double)(h >> 11) * 0x1p-52 - 1.0;
}

static double smooth(double t) { return t * t * (3.0 - 2.0 * t); }

/* Value noise: the lattice values interpolated with smoothstep weights. */
static double value_noise(uint64_t key, double x, double y) {
  double fx = floor(x), fy = floor(y);
  int64_t ix = (int64_t)fx, iy = (int64_t)fy;
  double tx = smooth(x - fx), ty = smooth(y - fy);
  double a = lattice(key, ix, iy), b = lattice(key, ix + 1, iy);
  double c = lattice(key, ix, iy + 1), d = lattice(key, ix + 1, iy + 1);
  double top = a + (b - a) * tx, bottom = c + (d - c) * tx;
  return top + (bottom - top) * ty;
}

/* Three octaves, the coarsest of the given period; about [-1, 1]. */
static double fbm(uint64_t key, double x, double y, double period) {
  double sum = 0, amp = 1, norm = 0;
  for (int o = 0; o < 3; o++) {
    sum += amp * value_noise(key + (uint64_t)o, x / period, y / period);
    norm += amp;
    amp *= 0.5;
    period *= 0.5;
  }
  return sum / norm;
}

static double uniform(ts_rng *r) { return (double)(ts_rng_next(r) >> 11) * 0x1p-53; }

/* --- the land partition ----------------------------------------------------- */

/* Deals the land classes out over the nx*ny cells inside the image, each
 * by its weight and at least once, shuffled; the margin cells draw theirs
 * by weight. */
static int deal_land(scene *s, ts_rng *r) {
  int land[MAX_CLASSES], nland = 0;
  double total = 0;
  for (int k = 0; k < s->nclass; k++)
    if (classes[k].role == LAND) {
      land[nland++] = k;
      total += classes[k].weight;
    }
  int inner = s->nx * s->ny, at = 0;
  uint8_t *deck = malloc((size_t)inner);
  if (deck == NULL) return TS_ENOMEM;
  for (int i = 0; i < nland; i++) {
    int n = i == nland - 1 ? inner - at : (int)((double)inner * classes[land[i]].weight / total + 0.5);
    if (n < 1) n = 1;
    if (n > inner - at - (nland - 1 - i)) n = inner - at - (nland - 1 - i); /* room for the rest */
    for (int j = 0; j < n; j++) deck[at++] = (uint8_t)(land[i] + 1);
  }
  for (int i = inner - 1; i > 0; i--) { /* Fisher-Yates */
    int j = (int)ts_rng_below(r, (uint32_t)i + 1);
    uint8_t t = deck[i];
    deck[i] = deck[j];
    deck[j] = t;
  }
  int gx = s->nx + 2;
  for (int cy = 0; cy < s->ny + 2; cy++)
    for (int cx = 0; cx < gx; cx++) {
      int inside = cx >= 1 && cx <= s->nx && cy >= 1 && cy <= s->ny;
      uint8_t id;
      if (inside) {
        id = deck[(cy - 1) * s->nx + (cx - 1)];
      } else {
        double u = uniform(r) * total;
        int i = 0;
        while (i < nland - 1 && u >= classes[land[i]].weight) u -= classes[land[i++]].weight;
        id = (uint8_t)(land[i] + 1);
      }
      s->cls[cy * gx + cx] = id;
      /* Jittered within the middle 70% of the cell: never two seeds close. */
      s->sx[cy * gx + cx] = ((double)(cx - 1) + 0.15 + 0.7 * uniform(r)) * s->cell;
      s->sy[cy * gx + cx] = ((double)(cy - 1) + 0.15 + 0.7 * uniform(r)) * s->cell;
    }
  free(deck);
  return 0;
}

/* The land class at warped point (x, y): its nearest Voronoi seed's. */
static uint8_t land_at(const scene *s, double x, double y) {
  int gx = s->nx + 2, gy = s->ny + 2;
  int cx = (int)floor(x / s->cell) + 1, cy = (int)floor(y / s->cell) + 1;
  double best = INFINITY;
  uint8_t id = 1;
  for (int j = cy - 1; j <= cy + 1; j++) {
    if (j < 0 || j >= gy) continue;
    for (int i = cx - 1; i <= cx + 1; i++) {
      if (i < 0 || i >= gx) continue;
      double dx = s->sx[j * gx + i] - x, dy = s->sy[j * gx + i] - y, d = dx * dx + dy * dy;
      if (d < best) {
        best = d;
        id = s->cls[j * gx + i];
      }
    }
  }
  return id;
}

/* --- settlements, lakes, the river ------------------------------------------------ */

static int add_disc(scene *s, double x, double y, double r, int id) {
  if (s->ndisc == s->cap) {
    int cap = s->cap ? 2 * s->cap : 64;
    disc *d = realloc(s->discs, (size_t)cap * sizeof(*d));
    if (d == NULL) return TS_ENOMEM;
    s->discs = d;
    s->cap = cap;
  }
  s->discs[s->ndisc++] = (disc){x, y, r, (uint8_t)id};
  return 0;
}

/* n groups of m discs (radius r0..r0+r1 cells) scattered within spread
 * cells of a centre placed in the middle 80% of the image. */
static int add_groups(scene *s, ts_rng *r, int id, int n, int m, double r0, double r1, double spread) {
  for (int g = 0; g < n; g++) {
    double cx = (0.1 + 0.8 * uniform(r)) * s->w, cy = (0.1 + 0.8 * uniform(r)) * s->h;
    for (int k = 0; k < m; k++) {
      double ox, oy;
      do { /* uniform in the unit disc */
        ox = 2 * uniform(r) - 1;
        oy = 2 * uniform(r) - 1;
      } while (ox * ox + oy * oy > 1);
      double rad = (r0 + r1 * uniform(r)) * s->cell;
      int rc = add_disc(s, cx + ox * spread * s->cell, cy + oy * spread * s->cell, rad, id);
      if (rc != 0) return rc;
    }
  }
  return 0;
}

/* How many of a feature an image of this many cells gets: `per256` for
 * the 256 cells of a square one, at least 1. */
static int count_for(const scene *s, double per256) {
  int n = (int)(per256 * (double)(s->nx * s->ny) / 256.0 + 0.5);
  return n < 1 ? 1 : n;
}

/* A river across the image along x (or y): its centre meanders by up to
 * 1.5 cells around a line in the middle 60%, its half width varies around
 * 0.22 cells. */
static int make_river(scene *s, ts_rng *r) {
  s->has_river = 1;
  s->river_vertical = (int)ts_rng_below(r, 2);
  int len = s->river_vertical ? s->h : s->w, across = s->river_vertical ? s->w : s->h;
  s->river_c = malloc((size_t)len * sizeof(double));
  s->river_hw = malloc((size_t)len * sizeof(double));
  if (s->river_c == NULL || s->river_hw == NULL) return TS_ENOMEM;
  double base = (0.2 + 0.6 * uniform(r)) * across;
  uint64_t key = mix64(s->seed ^ 0x726976ull);
  for (int t = 0; t < len; t++) {
    s->river_c[t] = base + 1.5 * s->cell * fbm(key, t, 0.5, 4 * s->cell);
    s->river_hw[t] = 0.22 * s->cell * (1 + 0.3 * fbm(key + 7, t, 0.5, 3 * s->cell));
  }
  return 0;
}

/* --- the warp ----------------------------------------------------------------------- */

/* The warp on a grid every `step` px (the finest octave is cell/4 long,
 * so step = cell/16 samples it 4 times per period; a pixel's warp is
 * interpolated between grid points). */
static int make_warp(scene *s) {
  s->step = (int)(s->cell / 16);
  if (s->step < 1) s->step = 1;
  s->gw = s->w / s->step + 2;
  s->gh = s->h / s->step + 2;
  size_t n = (size_t)s->gw * (size_t)s->gh;
  s->wx = malloc(n * sizeof(double));
  s->wy = malloc(n * sizeof(double));
  if (s->wx == NULL || s->wy == NULL) return TS_ENOMEM;
  uint64_t kx = mix64(s->seed ^ 0x77617270ull), ky = mix64(kx);
  double amp = WARP * s->cell;
  for (int j = 0; j < s->gh; j++)
    for (int i = 0; i < s->gw; i++) {
      double x = (double)i * s->step, y = (double)j * s->step;
      s->wx[(size_t)j * s->gw + i] = amp * fbm(kx, x, y, s->cell);
      s->wy[(size_t)j * s->gw + i] = amp * fbm(ky, x, y, s->cell);
    }
  return 0;
}

/* Row y's warped coordinates into px, py (w values each). */
static void warp_row(const scene *s, int y, double *px, double *py) {
  int j = y / s->step;
  double ty = (double)(y % s->step) / s->step;
  const double *x0 = s->wx + (size_t)j * s->gw, *x1 = x0 + s->gw;
  const double *y0 = s->wy + (size_t)j * s->gw, *y1 = y0 + s->gw;
  for (int x = 0; x < s->w; x++) {
    int i = x / s->step;
    double tx = (double)(x % s->step) / s->step;
    double a = x0[i] + (x0[i + 1] - x0[i]) * tx, b = x1[i] + (x1[i + 1] - x1[i]) * tx;
    double c = y0[i] + (y0[i + 1] - y0[i]) * tx, d = y1[i] + (y1[i + 1] - y1[i]) * tx;
    px[x] = x + a + (b - a) * ty;
    py[x] = y + c + (d - c) * ty;
  }
}

/* --- the class map --------------------------------------------------------------------- */

/* Row y of the map: land, then settlements and lakes (later discs over
 * earlier ones), then the river. */
static void map_row(const scene *s, int y, const double *px, const double *py, uint8_t *out) {
  for (int x = 0; x < s->w; x++) out[x] = land_at(s, px[x], py[x]);
  double slack = WARP * s->cell + 1; /* how far a warped point lies from its pixel */
  for (int k = 0; k < s->ndisc; k++) {
    const disc *d = &s->discs[k];
    if (y < d->y - d->r - slack || y > d->y + d->r + slack) continue;
    int x0 = (int)(d->x - d->r - slack), x1 = (int)(d->x + d->r + slack);
    if (x0 < 0) x0 = 0;
    if (x1 > s->w - 1) x1 = s->w - 1;
    for (int x = x0; x <= x1; x++) {
      double dx = px[x] - d->x, dy = py[x] - d->y;
      if (dx * dx + dy * dy < d->r * d->r) out[x] = d->id;
    }
  }
  if (!s->has_river) return;
  for (int x = 0; x < s->w; x++) {
    double along = s->river_vertical ? py[x] : px[x], across = s->river_vertical ? px[x] : py[x];
    int len = s->river_vertical ? s->h : s->w;
    int t = along < 0 ? 0 : along >= len ? len - 1 : (int)along;
    if (fabs(across - s->river_c[t]) < s->river_hw[t]) out[x] = 2;
  }
}

static int make_map(scene *s, uint8_t *map) {
  double *px = malloc((size_t)s->w * sizeof(double)), *py = malloc((size_t)s->w * sizeof(double));
  if (px == NULL || py == NULL) {
    free(px);
    free(py);
    return TS_ENOMEM;
  }
  for (int y = 0; y < s->h; y++) {
    warp_row(s, y, px, py);
    map_row(s, y, px, py, map + (size_t)y * s->w);
  }
  free(px);
  free(py);
  return 0;
}

/* --- roads and paths ------------------------------------------------------------------------ */

/* Sets the pixels within radius of segment a-b to value (a capsule). */
static void draw_segment(uint8_t *img, int w, int h, double ax, double ay, double bx, double by, double radius,
                         uint8_t value) {
  int x0 = (int)floor((ax < bx ? ax : bx) - radius), x1 = (int)ceil((ax > bx ? ax : bx) + radius);
  int y0 = (int)floor((ay < by ? ay : by) - radius), y1 = (int)ceil((ay > by ? ay : by) + radius);
  if (x0 < 0) x0 = 0;
  if (y0 < 0) y0 = 0;
  if (x1 > w - 1) x1 = w - 1;
  if (y1 > h - 1) y1 = h - 1;
  double dx = bx - ax, dy = by - ay, len2 = dx * dx + dy * dy;
  for (int y = y0; y <= y1; y++)
    for (int x = x0; x <= x1; x++) {
      /* Distance from the pixel centre to the nearest point of the segment. */
      double qx = x + 0.5 - ax, qy = y + 0.5 - ay;
      double t = len2 > 0 ? (qx * dx + qy * dy) / len2 : 0;
      t = t < 0 ? 0 : t > 1 ? 1 : t;
      double ex = qx - t * dx, ey = qy - t * dy;
      if (ex * ex + ey * ey <= radius * radius) img[(size_t)y * w + x] = value;
    }
}

/* A point on edge e (0 top, 1 right, 2 bottom, 3 left) of the image, at
 * fraction f along it. */
static void edge_point(const scene *s, int e, double f, double *x, double *y) {
  *x = e == 1 ? s->w : e == 3 ? 0 : f * s->w;
  *y = e == 2 ? s->h : e == 0 ? 0 : f * s->h;
}

/* A road or path as a polyline in pixel coordinates, and its radius. */
#define MAX_VERTICES 9
typedef struct {
  int is_road, n;
  double x[MAX_VERTICES], y[MAX_VERTICES], radius;
} polyline;

/* What becomes of each line: drawn into the road raster, or written as a
 * vector feature. */
typedef int (*line_fn)(void *ctx, const polyline *p);

/* A road from one edge to another (the opposite one, or a neighbour):
 * eight segments bending away from the straight line by a smoothed random
 * walk, 3, 5, 7 or 9 px wide. */
static void road_line(const scene *s, ts_rng *r, polyline *p) {
  int e0 = (int)ts_rng_below(r, 4), e1 = (e0 + 1 + (int)ts_rng_below(r, 3)) % 4;
  double ax, ay, bx, by;
  edge_point(s, e0, 0.1 + 0.8 * uniform(r), &ax, &ay);
  edge_point(s, e1, 0.1 + 0.8 * uniform(r), &bx, &by);
  double dx = bx - ax, dy = by - ay, len = sqrt(dx * dx + dy * dy);
  double nx = -dy / len, ny = dx / len; /* unit normal */
  p->is_road = 1;
  p->radius = (double)(3 + 2 * (int)ts_rng_below(r, 4)) / 2;
  p->n = 1;
  p->x[0] = ax;
  p->y[0] = ay;
  double off = 0;
  const int nseg = 8;
  for (int k = 1; k <= nseg; k++) {
    double t = (double)k / nseg;
    off = k == nseg ? 0 : 0.6 * off + (2 * uniform(r) - 1) * 0.06 * len;
    p->x[p->n] = ax + t * dx + off * nx;
    p->y[p->n++] = ay + t * dy + off * ny;
  }
}

/* A path: six segments from an inner point, turning a little at each. */
static void path_line(const scene *s, ts_rng *r, polyline *p) {
  double side = sqrt((double)s->w * s->h);
  double x = (0.1 + 0.8 * uniform(r)) * s->w, y = (0.1 + 0.8 * uniform(r)) * s->h;
  double seg = (0.15 + 0.15 * uniform(r)) * side / 6, dx, dy, n;
  do {
    dx = 2 * uniform(r) - 1;
    dy = 2 * uniform(r) - 1;
    n = dx * dx + dy * dy;
  } while (n > 1 || n < 0.01);
  n = sqrt(n);
  dx /= n;
  dy /= n;
  p->is_road = 0;
  p->radius = 1.0;
  p->n = 1;
  p->x[0] = x;
  p->y[0] = y;
  for (int k = 0; k < 6; k++) {
    double tx = dx + (2 * uniform(r) - 1) * 0.6, ty = dy + (2 * uniform(r) - 1) * 0.6;
    n = sqrt(tx * tx + ty * ty);
    dx = tx / n;
    dy = ty / n;
    x += dx * seg;
    y += dy * seg;
    p->x[p->n] = x;
    p->y[p->n++] = y;
  }
}

/* Paths first, so roads cross them on top. */
static int make_lines(const scene *s, line_fn each, void *ctx) {
  ts_rng r;
  polyline p;
  int side = (int)sqrt((double)s->w * s->h);
  int npath = 2 + side / 1024, nroad = 3 + side / 2048, rc = 0;
  ts_rng_seed(&r, s->seed, 5);
  for (int i = 0; rc == 0 && i < npath; i++) {
    path_line(s, &r, &p);
    rc = each(ctx, &p);
  }
  ts_rng_seed(&r, s->seed, 4);
  for (int i = 0; rc == 0 && i < nroad; i++) {
    road_line(s, &r, &p);
    rc = each(ctx, &p);
  }
  return rc;
}

/* The road raster's line_fn: ctx is the scene's road image. */
typedef struct {
  const scene *s;
  uint8_t *img;
} raster_ctx;

static int draw_line(void *ctx, const polyline *p) {
  const raster_ctx *c = ctx;
  for (int k = 1; k < p->n; k++)
    draw_segment(c->img, c->s->w, c->s->h, p->x[k - 1], p->y[k - 1], p->x[k], p->y[k], p->radius,
                 p->is_road ? ROAD : PATH);
  return 0;
}

/* --- the scene --------------------------------------------------------------------------------- */

static int scene_init(scene *s) {
  ts_rng r;
  s->cell = sqrt((double)s->w * s->h) / CELLS_ACROSS;
  s->nx = (int)ceil(s->w / s->cell);
  s->ny = (int)ceil(s->h / s->cell);
  size_t cells = (size_t)(s->nx + 2) * (size_t)(s->ny + 2);
  s->sx = malloc(cells * sizeof(double));
  s->sy = malloc(cells * sizeof(double));
  s->cls = malloc(cells);
  if (s->sx == NULL || s->sy == NULL || s->cls == NULL) return TS_ENOMEM;
  ts_rng_seed(&r, s->seed, 1);
  int rc = deal_land(s, &r);
  if (rc == 0) rc = make_warp(s);
  /* Town: 4 clusters of 8 discs 0.4..0.8 cells within 1.2 cells;
   * industry: 2 of 5 larger ones, closer together. */
  ts_rng_seed(&r, s->seed, 2);
  for (int k = 0; rc == 0 && k < s->nclass; k++) {
    if (classes[k].role != SETTLEMENT) continue;
    rc = k == 2 ? add_groups(s, &r, k + 1, count_for(s, 4), 8, 0.4, 0.4, 1.2)
                : add_groups(s, &r, k + 1, count_for(s, 2), 5, 0.55, 0.35, 0.7);
  }
  /* Water: 2 lakes of 3 discs 0.7..1.2 cells within 0.8 cells, a river. */
  ts_rng_seed(&r, s->seed, 3);
  if (rc == 0 && s->nclass >= 2) rc = add_groups(s, &r, 2, count_for(s, 2), 3, 0.7, 0.5, 0.8);
  if (rc == 0 && s->nclass >= 2) rc = make_river(s, &r);
  return rc;
}

static void scene_free(scene *s) {
  free(s->sx);
  free(s->sy);
  free(s->cls);
  free(s->wx);
  free(s->wy);
  free(s->discs);
  free(s->river_c);
  free(s->river_hw);
}

/* --- output: PNGs ----------------------------------------------------------------------------- */

static int write_plane(const char *prefix, const char *suffix, const ts_image *img, char *err) {
  char path[PATH_MAX];
  if (snprintf(path, sizeof(path), "%s-%s.png", prefix, suffix) >= (int)sizeof(path))
    return ts_error(err, TS_EINVAL, "-o %s: the path is too long", prefix);
  return ts_image_write(path, img, NULL, err);
}

static void print_classes(const scene *s, const uint64_t count[256]) {
  double n = (double)s->w * s->h;
  for (int k = 0; k < s->nclass; k++)
    printf("class %d %-10s %5.1f%%\n", k + 1, classes[k].name, 100.0 * (double)count[k + 1] / n);
}

/* Each class's share of the map, the lines' share of the raster. */
static void print_shares(const scene *s, const uint8_t *map, const uint8_t *roads) {
  uint64_t count[256] = {0}, lines[256] = {0};
  size_t n = (size_t)s->w * s->h;
  for (size_t i = 0; i < n; i++) {
    count[map[i]]++;
    lines[roads[i]]++;
  }
  print_classes(s, count);
  printf("roads (255) %.2f%%, paths (128) %.2f%%\n", 100.0 * (double)lines[ROAD] / (double)n,
         100.0 * (double)lines[PATH] / (double)n);
}

/* The whole map and road raster in memory, written as PNGs. */
static int write_pngs(const char *prefix, scene *s, char *err) {
  ts_image map = {0}, roads = {0};
  int rc;
  if ((rc = ts_image_alloc(&map, s->w, s->h, 1, TS_PIX_U8, err)) != 0 ||
      (rc = ts_image_alloc(&roads, s->w, s->h, 1, TS_PIX_U8, err)) != 0 || (rc = make_map(s, map.pixels)) != 0) {
    rc = ts_error(err, TS_ENOMEM, "out of memory for a %dx%d scene", s->w, s->h);
  } else {
    raster_ctx ctx = {s, roads.pixels};
    make_lines(s, draw_line, &ctx);
    if ((rc = write_plane(prefix, "classes", &map, err)) == 0 && (rc = write_plane(prefix, "roads", &roads, err)) == 0)
      print_shares(s, map.pixels, roads.pixels);
  }
  ts_image_free(&map);
  ts_image_free(&roads);
  return rc;
}

/* --- output: GIS files -------------------------------------------------------------------------- */

/* Where the GIS scene lies: its top-left corner (a UTM zone's false
 * easting, 5700 km north), the pixel size in the CRS's units. */
#define ORIGIN_X 500000.0
#define ORIGIN_Y 5700000.0
#define GIS_TILE 512 /* the class map's GeoTIFF tiles, and the strips it is made in */

typedef struct {
  FILE *f;
  double res;
  int nroad, npath;
} geojson_ctx;

/* A line as a GeoJSON feature: kind road or path, width in metres. */
static int write_feature(void *ctx, const polyline *p) {
  geojson_ctx *c = ctx;
  fprintf(c->f, "%s  {\"type\": \"Feature\", \"properties\": {\"kind\": \"%s\", \"width\": %g},\n"
                "   \"geometry\": {\"type\": \"LineString\", \"coordinates\": [",
          c->nroad + c->npath ? ",\n" : "", p->is_road ? "road" : "path", 2 * p->radius * c->res);
  for (int k = 0; k < p->n; k++)
    fprintf(c->f, "%s[%.4f, %.4f]", k ? ", " : "", ORIGIN_X + p->x[k] * c->res, ORIGIN_Y - p->y[k] * c->res);
  fprintf(c->f, "]}}");
  if (p->is_road) c->nroad++;
  else c->npath++;
  return 0;
}

/* PREFIX-SUFFIX into path, or an error. */
static int gis_path(char path[PATH_MAX], const char *prefix, const char *suffix, char *err) {
  if (snprintf(path, PATH_MAX, "%s-%s", prefix, suffix) >= PATH_MAX)
    return ts_error(err, TS_EINVAL, "-o %s: the path is too long", prefix);
  return 0;
}

/* The roads and paths as a GeoJSON layer in the scene's CRS (the 2008
 * "crs" member, which GDAL honours; RFC 7946 would force WGS 84), and the
 * line rules (gis.h) that draw them as mkscene's PNG does: roads 255 over
 * paths 128, each its own width. */
static int write_roads(const char *prefix, const scene *s, int epsg, double res, char *err) {
  char path[PATH_MAX];
  int rc = gis_path(path, prefix, "roads.geojson", err);
  FILE *f = rc == 0 ? fopen(path, "w") : NULL;
  if (rc == 0 && f == NULL) return ts_error(err, TS_EIO, "%s: cannot write it: %m", path);
  if (rc != 0) return rc;
  fprintf(f, "{\"type\": \"FeatureCollection\", \"name\": \"roads\",\n"
             " \"crs\": {\"type\": \"name\", \"properties\": {\"name\": \"urn:ogc:def:crs:EPSG::%d\"}},\n"
             " \"features\": [\n", epsg);
  geojson_ctx c = {f, res, 0, 0};
  make_lines(s, write_feature, &c);
  fprintf(f, "\n]}\n");
  if (fclose(f) != 0) return ts_error(err, TS_EIO, "%s: writing it failed: %m", path);
  if ((rc = gis_path(path, prefix, "lines.json", err)) != 0) return rc;
  if ((f = fopen(path, "w")) == NULL) return ts_error(err, TS_EIO, "%s: cannot write it: %m", path);
  fprintf(f, "{\"layer\": \"roads\", \"field\": \"kind\", \"width_field\": \"width\",\n"
             " \"rules\": [{\"match\": \"road\", \"value\": %d, \"width\": %g, \"order\": 2},\n"
             "           {\"match\": \"path\", \"value\": %d, \"width\": %g, \"order\": 1}]}\n",
          ROAD, 3 * res, PATH, 2 * res);
  if (fclose(f) != 0) return ts_error(err, TS_EIO, "%s: writing it failed: %m", path);
  printf("%d roads, %d paths as lines\n", c.nroad, c.npath);
  return 0;
}

/* The class map as a tiled GeoTIFF, made and written GIS_TILE rows at a
 * time: memory is one strip and GDAL's cache, whatever the size. */
static int write_classes_tif(const char *prefix, const scene *s, const ts_gis_georef *geo, char *err) {
  char path[PATH_MAX];
  int rc = gis_path(path, prefix, "classes.tif", err);
  if (rc != 0) return rc;
  uint8_t *strip = malloc((size_t)s->w * GIS_TILE);
  double *px = malloc((size_t)s->w * sizeof(double)), *py = malloc((size_t)s->w * sizeof(double));
  ts_gis_writer *w = NULL;
  uint64_t count[256] = {0};
  if (strip == NULL || px == NULL || py == NULL) rc = ts_error(err, TS_ENOMEM, "out of memory for a %d px row", s->w);
  if (rc == 0) rc = ts_gis_writer_create(path, s->w, s->h, 1, GIS_TILE, geo, 0, &w, err);
  for (int y0 = 0; rc == 0 && y0 < s->h; y0 += GIS_TILE) {
    int rows = s->h - y0 < GIS_TILE ? s->h - y0 : GIS_TILE;
    for (int j = 0; j < rows; j++) {
      uint8_t *row = strip + (size_t)j * s->w;
      warp_row(s, y0 + j, px, py);
      map_row(s, y0 + j, px, py, row);
      for (int x = 0; x < s->w; x++) count[row[x]]++;
    }
    rc = ts_gis_writer_put(w, 0, y0, s->w, rows, strip, err);
  }
  if (rc == 0) {
    rc = ts_gis_writer_finish(w, err);
    w = NULL;
  }
  ts_gis_writer_abort(w);
  free(strip);
  free(px);
  free(py);
  if (rc == 0) print_classes(s, count);
  return rc;
}

static int write_gis(const char *prefix, scene *s, int epsg, double res, char *err) {
  ts_gis_georef geo = {.has_geo = 1, .transform = {ORIGIN_X, res, 0, ORIGIN_Y, 0, -res}};
  char crs[32];
  snprintf(crs, sizeof(crs), "EPSG:%d", epsg);
  int rc = ts_gis_crs_wkt(crs, geo.crs_wkt, sizeof(geo.crs_wkt), err);
  if (rc == 0) rc = write_classes_tif(prefix, s, &geo, err);
  if (rc == 0) rc = write_roads(prefix, s, epsg, res, err);
  return rc;
}

/* --- options ----------------------------------------------------------------------------------- */

typedef struct {
  const char *prefix, *size;
  int w, h, nclass, gis, epsg, placed; /* placed: --crs or --pixel-size given */
  double res;
  uint64_t seed;
} options;

static int usage(const char *msg) {
  fprintf(stderr,
          "mkscene: %s\n"
          "usage: mkscene -o PREFIX [--size N|WxH] [--seed S] [--classes K] [--gis [--crs EPSG:N] [--pixel-size M]]\n"
          "  -o PREFIX      writes PREFIX-classes.png and PREFIX-roads.png\n"
          "  --size N|WxH   %d..%d a side (default 1024; to %d with --gis)\n"
          "  --seed S       0..2^64-1 (default 1)\n"
          "  --classes K    1..%d: 1 forest, 2 water, 3 town, 4 sand, 5 grassland, 6 arable,\n"
          "                 7 industrial, 8 wetland (default 4)\n"
          "  --gis          writes GIS files instead, made by strips in bounded memory:\n"
          "                 PREFIX-classes.tif (a tiled GeoTIFF, top-left at %.0f,%.0f),\n"
          "                 PREFIX-roads.geojson (the roads and paths as lines, kind and width\n"
          "                 in metres) and PREFIX-lines.json (line rules that draw them)\n"
          "  --crs EPSG:N   a projected CRS in metres (default EPSG:32632, UTM zone 32N)\n"
          "  --pixel-size M metres a pixel, 0.01..100 (default 0.25)\n",
          msg, MIN_SIDE, MAX_SIDE, MAX_GIS_SIDE, MAX_CLASSES, ORIGIN_X, ORIGIN_Y);
  return 2;
}

static int parse_size(options *o, char *msg, size_t cap) {
  int max = o->gis ? MAX_GIS_SIDE : MAX_SIDE;
  if (ts_parse_int(o->size, MIN_SIDE, max, &o->w) == 0) {
    o->h = o->w;
    return 0;
  }
  if (ts_parse_size(o->size, max, &o->w, &o->h) == 0 && o->w >= MIN_SIDE && o->h >= MIN_SIDE) return 0;
  snprintf(msg, cap, "--size %s: need N or WxH, %d..%d a side", o->size, MIN_SIDE, max);
  return usage(msg);
}

static int parse_options(int argc, char **argv, options *o) {
  static const struct option longs[] = {{"size", required_argument, 0, 's'},
                                        {"seed", required_argument, 0, 'S'},
                                        {"classes", required_argument, 0, 'k'},
                                        {"gis", no_argument, 0, 'g'},
                                        {"crs", required_argument, 0, 'c'},
                                        {"pixel-size", required_argument, 0, 'p'},
                                        {0, 0, 0, 0}};
  char msg[256];
  *o = (options){NULL, "1024", 1024, 1024, 4, 0, 32632, 0, 0.25, 1};
  int c;
  opterr = 0;
  while ((c = getopt_long(argc, argv, "o:", longs, NULL)) != -1) {
    switch (c) {
    case 'o':
      o->prefix = optarg;
      break;
    case 's':
      o->size = optarg;
      break;
    case 'S':
      if (ts_parse_u64(optarg, &o->seed) != 0) {
        snprintf(msg, sizeof(msg), "--seed %s: need a whole number 0..2^64-1", optarg);
        return usage(msg);
      }
      break;
    case 'k':
      if (ts_parse_int(optarg, 1, MAX_CLASSES, &o->nclass) != 0) {
        snprintf(msg, sizeof(msg), "--classes %s: need 1..%d", optarg, MAX_CLASSES);
        return usage(msg);
      }
      break;
    case 'g':
      o->gis = 1;
      break;
    case 'c':
      o->placed = 1;
      if (strncmp(optarg, "EPSG:", 5) != 0 || ts_parse_int(optarg + 5, 1024, 999999, &o->epsg) != 0) {
        snprintf(msg, sizeof(msg), "--crs %s: need EPSG:N", optarg);
        return usage(msg);
      }
      break;
    case 'p':
      o->placed = 1;
      if (ts_parse_double(optarg, &o->res) != 0 || !(o->res >= 0.01 && o->res <= 100)) {
        snprintf(msg, sizeof(msg), "--pixel-size %s: need 0.01..100 (metres)", optarg);
        return usage(msg);
      }
      break;
    default:
      snprintf(msg, sizeof(msg), "unknown option or missing value: %s", argv[optind - 1]);
      return usage(msg);
    }
  }
  if (optind < argc) {
    snprintf(msg, sizeof(msg), "unexpected argument: %s", argv[optind]);
    return usage(msg);
  }
  if (o->placed && !o->gis) return usage("--crs and --pixel-size place the --gis files: add --gis");
  int rc = parse_size(o, msg, sizeof(msg));
  if (rc != 0) return rc;
  if (o->prefix == NULL || o->prefix[0] == '\0') return usage("-o PREFIX is required");
  return 0;
}

int main(int argc, char **argv) {
  options o;
  char err[TS_ERR_LEN];
  int rc = parse_options(argc, argv, &o);
  if (rc != 0) return rc;
  /* Fail before the work if nothing can be written. */
  if ((o.gis ? ts_gis_lib_load(err) : ts_image_lib_load(err)) != 0) {
    fprintf(stderr, "mkscene: %s\n", err);
    return 1;
  }
  if (o.gis) { /* and for a CRS GDAL does not know, with the options' status */
    char wkt[4096], crs[32];
    snprintf(crs, sizeof(crs), "EPSG:%d", o.epsg);
    if (ts_gis_crs_wkt(crs, wkt, sizeof(wkt), err) != 0) {
      fprintf(stderr, "mkscene: --crs %s\n", err);
      return 2;
    }
  }
  scene s = {.w = o.w, .h = o.h, .nclass = o.nclass, .seed = o.seed};
  if (scene_init(&s) != 0) {
    fprintf(stderr, "mkscene: out of memory for a %dx%d scene\n", o.w, o.h);
    rc = 1;
  } else if ((o.gis ? write_gis(o.prefix, &s, o.epsg, o.res, err) : write_pngs(o.prefix, &s, err)) != 0) {
    fprintf(stderr, "mkscene: %s\n", err);
    rc = 1;
  }
  scene_free(&s);
  return rc;
}
