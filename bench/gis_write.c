/* gis_write.c - the GIS writer's (common/gis.h) time and memory at a
 * size: writes a W x H RGB image tile by tile in raster order, as a tiled
 * GeoTIFF or a COG, and prints the time of the puts and of finish (the
 * overviews and the COG copy) and the process's peak RSS, which must not
 * grow with the image (issue 28: a 32768² scene's output on a coordinator
 * of at most 2 GiB).
 *
 * The pixels are aerial-like for the compressor: smooth colour fields
 * with 3-bit noise, from integer hashing (the same bytes every run).
 * With --noise every byte is the hash's (incompressible: the file is as
 * large as the pixels, which takes a file past 4 GiB, where only BigTIFF's
 * 64-bit offsets reach; bench/bigtiff.py reads it back): byte c of pixel
 * (x, y) is bits 8c..8c+7 of hash(x * 0x9e3779b1 ^ y).
 *
 *   gis_write -o OUT.tif [--size N|WxH] [--tile T] [--cog] [--noise]
 *
 * Prints "puts S s, finish S s, peak RSS N MiB, file N MiB". Exit status
 * 2 for bad options, 1 for a failure. */
#include <getopt.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <time.h>

#include "error.h"
#include "gis.h"
#include "util.h"

static double now(void) {
  struct timespec t;
  clock_gettime(CLOCK_MONOTONIC, &t);
  return (double)t.tv_sec + 1e-9 * (double)t.tv_nsec;
}

static uint32_t hash(uint32_t x) {
  x ^= x >> 16;
  x *= 0x7feb352du;
  x ^= x >> 15;
  x *= 0x846ca68bu;
  return x ^ (x >> 16);
}

static void fill_tile(uint8_t *px, int tx, int ty, int rw, int rh, int noise) {
  for (int y = 0; y < rh; y++)
    for (int x = 0; x < rw; x++) {
      uint32_t gx = (uint32_t)(tx + x), gy = (uint32_t)(ty + y);
      uint32_t n = hash(gx * 0x9e3779b1u ^ gy);
      uint8_t *p = px + ((size_t)y * rw + x) * 3;
      if (noise) {
        p[0] = (uint8_t)n, p[1] = (uint8_t)(n >> 8), p[2] = (uint8_t)(n >> 16);
        continue;
      }
      p[0] = (uint8_t)(((gx >> 6) + (gy >> 7)) * 5 + (n & 7));
      p[1] = (uint8_t)(((gx >> 7) * 3 + (gy >> 6)) * 2 + ((n >> 3) & 7));
      p[2] = (uint8_t)(((gx ^ gy) >> 8) * 7 + ((n >> 6) & 7));
    }
}

static int usage(const char *msg) {
  fprintf(stderr, "gis_write: %s\nusage: gis_write -o OUT.tif [--size N|WxH] [--tile T] [--cog] [--noise]\n", msg);
  return 2;
}

int main(int argc, char **argv) {
  static const struct option longs[] = {{"size", required_argument, 0, 's'},
                                        {"tile", required_argument, 0, 't'},
                                        {"cog", no_argument, 0, 'c'},
                                        {"noise", no_argument, 0, 'n'},
                                        {0, 0, 0, 0}};
  const char *out = NULL;
  int w = 4096, h = 4096, tile = 1024, cog = 0, noise = 0, c;
  opterr = 0;
  while ((c = getopt_long(argc, argv, "o:", longs, NULL)) != -1) {
    if (c == 'o') out = optarg;
    else if (c == 's' && ts_parse_int(optarg, 16, 1 << 20, &w) == 0) h = w;
    else if (c == 's' && ts_parse_size(optarg, 1 << 20, &w, &h) == 0) continue;
    else if (c == 't' && ts_parse_int(optarg, 16, 4096, &tile) == 0) continue;
    else if (c == 'c') cog = 1;
    else if (c == 'n') noise = 1;
    else return usage("bad option or value");
  }
  if (out == NULL || optind < argc) return usage("-o OUT.tif is required, and nothing else");
  char err[TS_ERR_LEN];
  ts_gis_georef g = {.has_geo = 1, .transform = {500000, 0.25, 0, 5700000, 0, -0.25}};
  ts_gis_writer *wr;
  uint8_t *px = malloc((size_t)tile * tile * 3);
  if (px == NULL || ts_gis_crs_wkt("EPSG:32632", g.crs_wkt, sizeof(g.crs_wkt), err) != 0 ||
      ts_gis_writer_create(out, w, h, 3, tile, &g, cog, &wr, err) != 0) {
    fprintf(stderr, "gis_write: %s\n", px == NULL ? "out of memory" : err);
    return 1;
  }
  double t0 = now();
  for (int ty = 0; ty < h; ty += tile)
    for (int tx = 0; tx < w; tx += tile) {
      int rw = w - tx < tile ? w - tx : tile, rh = h - ty < tile ? h - ty : tile;
      fill_tile(px, tx, ty, rw, rh, noise);
      if (ts_gis_writer_put(wr, tx, ty, rw, rh, px, err) != 0) {
        fprintf(stderr, "gis_write: %s\n", err);
        ts_gis_writer_abort(wr);
        return 1;
      }
    }
  double t1 = now();
  if (ts_gis_writer_finish(wr, err) != 0) {
    fprintf(stderr, "gis_write: %s\n", err);
    return 1;
  }
  double t2 = now();
  struct rusage ru;
  getrusage(RUSAGE_SELF, &ru);
  struct stat st;
  stat(out, &st);
  printf("%dx%d tile %d%s: puts %.1f s, finish %.1f s, peak RSS %ld MiB, file %lld MiB\n", w, h, tile,
         cog ? " COG" : "", t1 - t0, t2 - t1, ru.ru_maxrss / 1024, (long long)st.st_size >> 20);
  free(px);
  return 0;
}
