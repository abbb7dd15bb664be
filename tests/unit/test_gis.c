/* test_gis.c - common/gis.h against real GDAL on small generated files:
 * rasters read by region equal the whole read (0 outside), bad rasters
 * refused clearly; the writer's round trip (bytes, georeferencing, tiles,
 * compression), its COG (overviews, layout), abort leaving nothing; vector
 * lines rasterised by tiles stitched equal the whole, drawn by the rules
 * (value, width in map units or pixels, per-feature width, draw order),
 * reprojected from lon/lat, a layer without CRS placed or refused as gis.h
 * decides; the rules' JSON form. What is tested goes through
 * libtexsyn-gis.so (TEXSYN_GIS_LIB); fixtures are made and outputs checked
 * with GDAL directly, an independent reader. */
#include <cpl_conv.h>
#include <cpl_error.h>
#include <gdal.h>
#include <ogr_api.h>
#include <ogr_srs_api.h>
#include <pthread.h>
#include <stdio.h>
#include <sys/stat.h>

#include "error.h"
#include "gis.h"
#include "ts_test.h"

/* The scenes' grid: UTM zone 32N at 0.25 m a pixel. */
#define X0 500000.0
#define Y0 5700000.0
#define RES 0.25

static char dir[64];

static void make_dir(void) {
  snprintf(dir, sizeof(dir), "/tmp/ts-gis-XXXXXX");
  assert_non_null(mkdtemp(dir));
  GDALAllRegister();
  CPLSetErrorHandler(CPLQuietErrorHandler);
}

static void remove_dir(void) {
  char cmd[128];
  snprintf(cmd, sizeof(cmd), "rm -rf %s", dir);
  assert_int_equal(system(cmd), 0);
}

static const char *in_dir(const char *name) {
  static char path[4][128];
  static int k;
  k = (k + 1) % 4;
  snprintf(path[k], sizeof(path[k]), "%s/%s", dir, name);
  return path[k];
}

static void utm_georef(ts_gis_georef *g) {
  char err[TS_ERR_LEN];
  memset(g, 0, sizeof(*g));
  g->has_geo = 1;
  double t[6] = {X0, RES, 0, Y0, 0, -RES};
  memcpy(g->transform, t, sizeof(t));
  assert_int_equal(ts_gis_crs_wkt("EPSG:32632", g->crs_wkt, sizeof(g->crs_wkt), err), 0);
}

/* A w x h raster of bands bands of type t, value(x, y) in every band,
 * georeferenced in UTM 32N; nodata if has_nodata. */
static void make_raster(const char *path, int w, int h, int bands, GDALDataType t, double (*value)(int, int),
                        int has_nodata, double nodata) {
  GDALDriverH d = GDALGetDriverByName("GTiff");
  char *opts[] = {"TILED=YES", "BLOCKXSIZE=32", "BLOCKYSIZE=32", "COMPRESS=DEFLATE", NULL};
  GDALDatasetH ds = GDALCreate(d, path, w, h, bands, t, opts);
  assert_non_null(ds);
  ts_gis_georef g;
  utm_georef(&g);
  assert_int_equal(GDALSetGeoTransform(ds, g.transform), CE_None);
  assert_int_equal(GDALSetProjection(ds, g.crs_wkt), CE_None);
  double *row = malloc((size_t)w * sizeof(*row));
  for (int b = 1; b <= bands; b++) {
    GDALRasterBandH band = GDALGetRasterBand(ds, b);
    if (has_nodata) GDALSetRasterNoDataValue(band, nodata);
    for (int y = 0; y < h; y++) {
      for (int x = 0; x < w; x++) row[x] = value(x, y);
      assert_int_equal(GDALRasterIO(band, GF_Write, 0, y, w, 1, row, w, 1, GDT_Float64, 0, 0), CE_None);
    }
  }
  free(row);
  GDALClose(ds);
}

static double classes(int x, int y) { return (double)((x / 7 + 3 * (y / 5)) % 9 + 1); }

/* --- rasters ------------------------------------------------------------- */

static void region_equals_whole(GDALDataType t) {
  const char *path = in_dir("classes.tif");
  int W = 150, H = 100;
  make_raster(path, W, H, 1, t, classes, 0, 0);
  char err[TS_ERR_LEN] = "";
  ts_gis_raster *r;
  int w, h;
  ts_gis_georef g, want;
  assert_int_equal(ts_gis_raster_open(path, &r, &w, &h, &g, err), 0);
  assert_int_equal(w, W);
  assert_int_equal(h, H);
  utm_georef(&want);
  assert_int_equal(g.has_geo, 1);
  assert_memory_equal(g.transform, want.transform, sizeof(want.transform));
  assert_non_null(strstr(g.crs_wkt, "UTM zone 32N"));
  uint16_t *whole = malloc((size_t)W * H * 2);
  assert_int_equal(ts_gis_raster_read(r, 0, 0, W, H, whole, err), 0);
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++) assert_int_equal(whole[y * W + x], classes(x, y));
  /* Regions inside, across the edges, and wholly outside. */
  static const int reg[][4] = {{10, 20, 33, 17}, {-5, -7, 40, 30}, {130, 90, 64, 64}, {-10, 40, 200, 3},
                               {200, 0, 8, 8},   {0, -20, 5, 10}};
  for (size_t k = 0; k < sizeof(reg) / sizeof(reg[0]); k++) {
    int rx = reg[k][0], ry = reg[k][1], rw = reg[k][2], rh = reg[k][3];
    uint16_t *part = malloc((size_t)rw * rh * 2);
    assert_int_equal(ts_gis_raster_read(r, rx, ry, rw, rh, part, err), 0);
    for (int y = 0; y < rh; y++)
      for (int x = 0; x < rw; x++) {
        int sx = rx + x, sy = ry + y;
        int in = sx >= 0 && sy >= 0 && sx < W && sy < H;
        assert_int_equal(part[y * rw + x], in ? whole[sy * W + sx] : 0);
      }
    free(part);
  }
  free(whole);
  ts_gis_raster_close(r);
}

static void raster_byte(void **state) {
  (void)state;
  make_dir();
  region_equals_whole(GDT_Byte);
  remove_dir();
}

static void raster_int32(void **state) {
  (void)state;
  make_dir();
  region_equals_whole(GDT_Int32);
  remove_dir();
}

static double big_at_corner(int x, int y) { return x == 3 && y == 2 ? 70000 : 1; }
static double edge_nodata(int x, int y) { return x == 0 ? 255 : (double)(y % 3 + 1); }

/* path must fail to open with code and a message holding want. */
static void open_refused(const char *path, int code, const char *want) {
  char err[TS_ERR_LEN] = "";
  ts_gis_raster *r = (ts_gis_raster *)1;
  int w, h;
  int rc = ts_gis_raster_open(path, &r, &w, &h, NULL, err);
  if (rc != code || strstr(err, want) == NULL || strstr(err, path) == NULL)
    fail_msg("%s: gave %d \"%s\", want %d \"...%s...\"", path, rc, err, code, want);
  assert_null(r);
}

static void raster_bad_files(void **state) {
  (void)state;
  make_dir();
  open_refused(in_dir("missing.tif"), TS_ENOENT, "no such file");
  const char *text = in_dir("text.tif");
  FILE *f = fopen(text, "w");
  fputs("not a raster\n", f);
  fclose(f);
  open_refused(text, TS_EFORMAT, "not a raster GDAL reads");
  make_raster(in_dir("rgb.tif"), 16, 16, 3, GDT_Byte, classes, 0, 0);
  open_refused(in_dir("rgb.tif"), TS_EFORMAT, "3 bands: a class map has one band");
  make_raster(in_dir("float.tif"), 16, 16, 1, GDT_Float32, classes, 0, 0);
  open_refused(in_dir("float.tif"), TS_EFORMAT, "type Float32: class ids need an integer type");
  /* Too large an id: named with its pixel, at the read that meets it. */
  make_raster(in_dir("big.tif"), 16, 16, 1, GDT_UInt32, big_at_corner, 0, 0);
  char err[TS_ERR_LEN] = "";
  ts_gis_raster *r;
  int w, h;
  uint16_t px[64];
  assert_int_equal(ts_gis_raster_open(in_dir("big.tif"), &r, &w, &h, NULL, err), 0);
  assert_int_equal(ts_gis_raster_read(r, 8, 8, 8, 8, px, err), 0);
  assert_int_equal(ts_gis_raster_read(r, 0, 0, 8, 8, px, err), TS_ETOOBIG);
  assert_non_null(strstr(err, "pixel 3,2 holds 70000: class ids are 0..65535"));
  /* Bad regions. */
  assert_int_equal(ts_gis_raster_read(r, 0, 0, 0, 8, px, err), TS_EINVAL);
  assert_int_equal(ts_gis_raster_read(r, 0, 0, 1 << 15, 1 << 15, px, err), TS_EINVAL);
  ts_gis_raster_close(r);
  /* Nodata reads as 0. */
  make_raster(in_dir("nodata.tif"), 16, 16, 1, GDT_Byte, edge_nodata, 1, 255);
  assert_int_equal(ts_gis_raster_open(in_dir("nodata.tif"), &r, &w, &h, NULL, err), 0);
  assert_int_equal(ts_gis_raster_read(r, 0, 0, 8, 8, px, err), 0);
  assert_int_equal(px[0], 0);
  assert_int_equal(px[1], 1);
  assert_int_equal(px[8 * 2 + 1], 3);
  ts_gis_raster_close(r);
  remove_dir();
}

/* --- the writer ------------------------------------------------------------ */

static uint8_t pixel(int x, int y, int c) { return (uint8_t)((x * 3 + y * 5 + c * 70 + (x * y) % 17) & 255); }

/* Writes a W x H RGB image tile by tile (edge tiles partial). */
static void write_image(const char *path, int W, int H, int tile, int cog) {
  char err[TS_ERR_LEN] = "";
  ts_gis_georef g;
  utm_georef(&g);
  ts_gis_writer *w;
  assert_int_equal(ts_gis_writer_create(path, W, H, 3, tile, &g, cog, &w, err), 0);
  uint8_t *px = malloc((size_t)tile * tile * 3);
  for (int ty = 0; ty < H; ty += tile)
    for (int tx = 0; tx < W; tx += tile) {
      int rw = W - tx < tile ? W - tx : tile, rh = H - ty < tile ? H - ty : tile;
      for (int y = 0; y < rh; y++)
        for (int x = 0; x < rw; x++)
          for (int c = 0; c < 3; c++) px[(y * rw + x) * 3 + c] = pixel(tx + x, ty + y, c);
      assert_int_equal(ts_gis_writer_put(w, tx, ty, rw, rh, px, err), 0);
    }
  free(px);
  struct stat st;
  char part[160];
  snprintf(part, sizeof(part), "%s.part", path);
  assert_int_equal(stat(part, &st), 0); /* written aside ... */
  assert_int_equal(ts_gis_writer_finish(w, err), 0);
  assert_int_not_equal(stat(part, &st), 0); /* ... and moved into place */
  assert_int_equal(stat(path, &st), 0);
}

/* The file at path holds write_image's pixels and georeferencing. */
static GDALDatasetH check_image(const char *path, int W, int H) {
  GDALDatasetH ds = GDALOpen(path, GA_ReadOnly);
  assert_non_null(ds);
  assert_int_equal(GDALGetRasterXSize(ds), W);
  assert_int_equal(GDALGetRasterYSize(ds), H);
  assert_int_equal(GDALGetRasterCount(ds), 3);
  uint8_t *px = malloc((size_t)W * H * 3);
  assert_int_equal(GDALDatasetRasterIO(ds, GF_Read, 0, 0, W, H, px, W, H, GDT_Byte, 3, NULL, 3, W * 3, 1), CE_None);
  for (int y = 0; y < H; y++)
    for (int x = 0; x < W; x++)
      for (int c = 0; c < 3; c++)
        if (px[(y * W + x) * 3 + c] != pixel(x, y, c)) fail_msg("%s: pixel %d,%d channel %d differs", path, x, y, c);
  free(px);
  ts_gis_georef want;
  utm_georef(&want);
  double t[6];
  assert_int_equal(GDALGetGeoTransform(ds, t), CE_None);
  assert_memory_equal(t, want.transform, sizeof(t));
  OGRSpatialReferenceH s = OSRNewSpatialReference(want.crs_wkt);
  assert_true(OSRIsSame(GDALGetSpatialRef(ds), s));
  OSRDestroySpatialReference(s);
  const char *comp = GDALGetMetadataItem(ds, "COMPRESSION", "IMAGE_STRUCTURE");
  assert_non_null(comp);
  assert_string_equal(comp, "DEFLATE");
  return ds;
}

static void writer_round_trip(void **state) {
  (void)state;
  make_dir();
  const char *path = in_dir("out.tif");
  write_image(path, 200, 150, 64, 0);
  GDALDatasetH ds = check_image(path, 200, 150);
  int bx, by;
  GDALGetBlockSize(GDALGetRasterBand(ds, 1), &bx, &by);
  assert_int_equal(bx, 64);
  assert_int_equal(by, 64);
  assert_int_equal(GDALGetOverviewCount(GDALGetRasterBand(ds, 1)), 0);
  GDALClose(ds);
  remove_dir();
}

static void writer_cog(void **state) {
  (void)state;
  make_dir();
  const char *path = in_dir("out-cog.tif");
  write_image(path, 1000, 700, 128, 1);
  GDALDatasetH ds = check_image(path, 1000, 700);
  GDALRasterBandH b = GDALGetRasterBand(ds, 1);
  /* Halving down to one tile: 500x350, 250x175, 125x88. */
  assert_int_equal(GDALGetOverviewCount(b), 3);
  assert_int_equal(GDALGetRasterBandXSize(GDALGetOverview(b, 0)), 500);
  assert_int_equal(GDALGetRasterBandXSize(GDALGetOverview(b, 2)), 125);
  const char *layout = GDALGetMetadataItem(ds, "LAYOUT", "IMAGE_STRUCTURE");
  assert_non_null(layout);
  assert_string_equal(layout, "COG");
  int bx, by;
  GDALGetBlockSize(b, &bx, &by);
  assert_int_equal(bx, 128);
  GDALClose(ds);
  /* Nothing left beside it. */
  struct stat st;
  assert_int_not_equal(stat(in_dir("out-cog.tif.part"), &st), 0);
  assert_int_not_equal(stat(in_dir("out-cog.tif.cog.part"), &st), 0);
  remove_dir();
}

/* The first 4 bytes of a TIFF: "II*\0" classic, "II+\0" BigTIFF. */
static int is_bigtiff(const char *path) {
  unsigned char b[4] = {0};
  FILE *f = fopen(path, "rb");
  assert_non_null(f);
  assert_int_equal(fread(b, 1, 4, f), 4);
  fclose(f);
  assert_true(b[0] == 'I' && b[1] == 'I' && (b[2] == 42 || b[2] == 43));
  return b[2] == 43;
}

/* A W x H RGB file with one tile put (the others read as 0). */
static void write_one_tile(const char *path, int W, int H) {
  char err[TS_ERR_LEN] = "";
  ts_gis_writer *w;
  assert_int_equal(ts_gis_writer_create(path, W, H, 3, 1024, NULL, 0, &w, err), 0);
  uint8_t *px = malloc(1024 * 1024 * 3);
  memset(px, 200, 1024 * 1024 * 3);
  assert_int_equal(ts_gis_writer_put(w, 1024, 0, 1024, 1024, px, err), 0);
  free(px);
  assert_int_equal(ts_gis_writer_finish(w, err), 0);
}

/* BigTIFF for an image that may pass 4 GiB, classic TIFF for a small one;
 * tiles never put take no room and read as 0. */
static void writer_bigtiff_when_needed(void **state) {
  (void)state;
  make_dir();
  write_one_tile(in_dir("big.tif"), 40000, 40000); /* 4.8 GB of RGB */
  assert_true(is_bigtiff(in_dir("big.tif")));
  write_one_tile(in_dir("small.tif"), 20000, 20000); /* 1.2 GB */
  assert_false(is_bigtiff(in_dir("small.tif")));
  struct stat st;
  assert_int_equal(stat(in_dir("big.tif"), &st), 0);
  assert_true(st.st_size < 1 << 20);
  GDALDatasetH ds = GDALOpen(in_dir("big.tif"), GA_ReadOnly);
  assert_non_null(ds);
  uint8_t px[2 * 3];
  assert_int_equal(GDALDatasetRasterIO(ds, GF_Read, 1023, 5, 2, 1, px, 2, 1, GDT_Byte, 3, NULL, 3, 6, 1), CE_None);
  static const uint8_t want[] = {0, 0, 0, 200, 200, 200};
  assert_memory_equal(px, want, 6);
  GDALClose(ds);
  remove_dir();
}

static void writer_abort_and_errors(void **state) {
  (void)state;
  make_dir();
  char err[TS_ERR_LEN] = "";
  ts_gis_writer *w;
  const char *path = in_dir("aborted.tif");
  assert_int_equal(ts_gis_writer_create(path, 256, 256, 3, 64, NULL, 1, &w, err), 0);
  uint8_t px[64 * 64 * 3] = {0};
  assert_int_equal(ts_gis_writer_put(w, 0, 0, 64, 64, px, err), 0);
  /* A region not inside the image. */
  assert_int_equal(ts_gis_writer_put(w, 200, 0, 64, 64, px, err), TS_EINVAL);
  assert_non_null(strstr(err, "region 64x64 at 200,0 is not inside the 256x256 image"));
  ts_gis_writer_abort(w);
  struct stat st;
  assert_int_not_equal(stat(path, &st), 0);
  assert_int_not_equal(stat(in_dir("aborted.tif.part"), &st), 0);
  /* Bad arguments, an unwritable place. */
  assert_int_equal(ts_gis_writer_create(path, 256, 256, 3, 100, NULL, 0, &w, err), TS_EINVAL);
  assert_non_null(strstr(err, "a multiple of 16"));
  assert_null(w);
  assert_int_equal(ts_gis_writer_create(path, 256, 256, 5, 64, NULL, 0, &w, err), TS_EINVAL);
  assert_int_equal(ts_gis_writer_create("/nonexistent-dir/x.tif", 256, 256, 3, 64, NULL, 0, &w, err), TS_EIO);
  assert_non_null(strstr(err, "/nonexistent-dir/x.tif.part: cannot create it"));
  remove_dir();
}

/* --- vector lines ------------------------------------------------------------ */

/* The test layer, in scene pixels: kind, width (0: none), vertices. */
typedef struct {
  const char *kind;
  double width;
  int n;
  double v[3][2];
} test_line;

static const test_line lines[] = {
    {"road", 0, 3, {{-20, 50}, {300, 200}, {540, 180}}},
    {"path", 0, 2, {{100, 0}, {120, 390}}},
    {"road", 6, 2, {{0, 300}, {512, 320}}},
    {"river", 0, 2, {{50, 50}, {450, 60}}},
};
#define NLINES ((int)(sizeof(lines) / sizeof(lines[0])))
#define SW 512
#define SH 384

/* Scene pixel -> map (UTM), then optionally to lon/lat. */
static void vertex(double px, double py, OGRCoordinateTransformationH to_ll, double *x, double *y) {
  *x = X0 + px * RES;
  *y = Y0 - py * RES;
  if (to_ll != NULL) assert_true(OCTTransform(to_ll, 1, x, y, NULL));
}

/* UTM 32N to lon/lat, x east and y north both. */
static OGRCoordinateTransformationH utm_to_lonlat(void) {
  OGRSpatialReferenceH u = OSRNewSpatialReference(NULL), ll = OSRNewSpatialReference(NULL);
  OSRImportFromEPSG(u, 32632);
  OSRImportFromEPSG(ll, 4326);
  OSRSetAxisMappingStrategy(u, OAMS_TRADITIONAL_GIS_ORDER);
  OSRSetAxisMappingStrategy(ll, OAMS_TRADITIONAL_GIS_ORDER);
  OGRCoordinateTransformationH t = OCTNewCoordinateTransformation(u, ll);
  assert_non_null(t);
  OSRDestroySpatialReference(u);
  OSRDestroySpatialReference(ll);
  return t;
}

/* The layer as GeoJSON: crs "" for none (GDAL then takes RFC 7946's
 * WGS 84), "EPSG::32632" with UTM vertices, "EPSG::4326" with lon/lat. */
static void write_geojson(const char *path, const char *crs) {
  OGRCoordinateTransformationH to_ll = strcmp(crs, "EPSG::4326") == 0 ? utm_to_lonlat() : NULL;
  FILE *f = fopen(path, "w");
  assert_non_null(f);
  fprintf(f, "{\"type\": \"FeatureCollection\",\n");
  if (crs[0] != '\0')
    fprintf(f, " \"crs\": {\"type\": \"name\", \"properties\": {\"name\": \"urn:ogc:def:crs:%s\"}},\n", crs);
  fprintf(f, " \"features\": [\n");
  for (int i = 0; i < NLINES; i++) {
    fprintf(f, "  {\"type\": \"Feature\", \"properties\": {\"kind\": \"%s\"", lines[i].kind);
    if (lines[i].width > 0) fprintf(f, ", \"width\": %g", lines[i].width);
    fprintf(f, "}, \"geometry\": {\"type\": \"LineString\", \"coordinates\": [");
    for (int k = 0; k < lines[i].n; k++) {
      double x, y;
      vertex(lines[i].v[k][0], lines[i].v[k][1], to_ll, &x, &y);
      fprintf(f, "%s[%.12f, %.12f]", k ? ", " : "", x, y);
    }
    fprintf(f, "]}}%s\n", i + 1 < NLINES ? "," : "");
  }
  fprintf(f, "]}\n");
  fclose(f);
  if (to_ll != NULL) OCTDestroyCoordinateTransformation(to_ll);
}

/* The layer as a Shapefile without .prj (no CRS), in UTM, in lon/lat or
 * in the scene's pixels. */
enum { IN_UTM, IN_LONLAT, IN_PIXELS };
static void write_shapefile(const char *path, int coords) {
  OGRCoordinateTransformationH to_ll = coords == IN_LONLAT ? utm_to_lonlat() : NULL;
  GDALDatasetH ds = GDALCreate(GDALGetDriverByName("ESRI Shapefile"), path, 0, 0, 0, GDT_Unknown, NULL);
  assert_non_null(ds);
  OGRLayerH layer = GDALDatasetCreateLayer(ds, "roads", NULL, wkbLineString, NULL);
  assert_non_null(layer);
  OGRFieldDefnH fk = OGR_Fld_Create("kind", OFTString), fw = OGR_Fld_Create("width", OFTReal);
  OGR_L_CreateField(layer, fk, TRUE);
  OGR_L_CreateField(layer, fw, TRUE);
  OGR_Fld_Destroy(fk);
  OGR_Fld_Destroy(fw);
  for (int i = 0; i < NLINES; i++) {
    OGRFeatureH f = OGR_F_Create(OGR_L_GetLayerDefn(layer));
    OGR_F_SetFieldString(f, 0, lines[i].kind);
    if (lines[i].width > 0) OGR_F_SetFieldDouble(f, 1, lines[i].width);
    OGRGeometryH g = OGR_G_CreateGeometry(wkbLineString);
    for (int k = 0; k < lines[i].n; k++) {
      double x, y;
      vertex(lines[i].v[k][0], lines[i].v[k][1], to_ll, &x, &y);
      if (coords == IN_PIXELS) x = lines[i].v[k][0], y = lines[i].v[k][1];
      OGR_G_AddPoint_2D(g, x, y);
    }
    OGR_F_SetGeometryDirectly(f, g);
    assert_int_equal(OGR_L_CreateFeature(layer, f), OGRERR_NONE);
    OGR_F_Destroy(f);
  }
  GDALClose(ds);
  if (to_ll != NULL) OCTDestroyCoordinateTransformation(to_ll);
}

/* Roads 3 m wide (per-feature "width" overrides), over paths 2 px wide. */
static void test_rules(ts_gis_line_rules *r) {
  memset(r, 0, sizeof(*r));
  strcpy(r->field, "kind");
  strcpy(r->width_field, "width");
  r->nrule = 2;
  r->rule[0] = (ts_gis_line_rule){"path", 128, 2, TS_GIS_UNIT_PIXEL, 1};
  r->rule[1] = (ts_gis_line_rule){"road", 255, 3, TS_GIS_UNIT_MAP, 2};
}

/* The whole scene's lines of the layer at path (scene: UTM grid). */
static uint8_t *read_lines_by(const char *path, const ts_gis_georef *scene, const ts_gis_line_rules *rules,
                              int *reprojected) {
  char err[TS_ERR_LEN] = "";
  ts_gis_lines *l;
  if (ts_gis_lines_open(path, scene, SW, SH, rules, &l, err) != 0) fail_msg("%s", err);
  int n;
  ts_gis_lines_info(l, &n, reprojected);
  assert_int_equal(n, 3); /* the river takes no rule */
  uint8_t *whole = malloc(SW * SH);
  assert_int_equal(ts_gis_lines_read(l, 0, 0, SW, SH, whole, err), 0);
  ts_gis_lines_close(l);
  return whole;
}

static uint8_t *read_lines(const char *path, const ts_gis_georef *scene, int *reprojected) {
  ts_gis_line_rules rules;
  test_rules(&rules);
  return read_lines_by(path, scene, &rules, reprojected);
}

static void lines_tiles_stitch_to_whole(void **state) {
  (void)state;
  make_dir();
  const char *path = in_dir("roads.geojson");
  write_geojson(path, "EPSG::32632");
  ts_gis_georef g;
  utm_georef(&g);
  int reprojected;
  uint8_t *whole = read_lines(path, &g, &reprojected);
  assert_int_equal(reprojected, 0);
  /* What the rules draw: only 0, 128, 255; roads over paths where they
   * cross; the per-feature 6 m (24 px) road wider than the 3 m (12 px) one. */
  long count[256] = {0};
  for (int i = 0; i < SW * SH; i++) count[whole[i]]++;
  assert_int_equal(count[0] + count[128] + count[255], SW * SH);
  assert_true(count[128] > 300 && count[255] > 5000);
  assert_int_equal(whole[108 * SW + 105], 255); /* the crossing */
  assert_int_equal(whole[350 * SW + 117], 128); /* the path, away from roads */
  assert_int_equal(whole[350 * SW + 121], 0);   /* 2 px wide: not 3 px off its centre */
  int road1 = 0, road2 = 0;
  for (int y = 0; y < SH; y++) {
    road1 += whole[y * SW + 400] == 255 && y < 250;
    road2 += whole[y * SW + 400] == 255 && y >= 250;
  }
  assert_in_range(road1, 11, 14); /* 3 m across at 0.25 m a pixel, slanted a little */
  assert_in_range(road2, 23, 26); /* 6 m */
  /* Tiles of a size that divides nothing, over and past the edges. */
  ts_gis_line_rules rules;
  test_rules(&rules);
  char err[TS_ERR_LEN] = "";
  ts_gis_lines *l;
  assert_int_equal(ts_gis_lines_open(path, &g, SW, SH, &rules, &l, err), 0);
  int tw = 100, th = 70;
  uint8_t *tile = malloc((size_t)tw * th);
  for (int ty = -th / 2; ty < SH; ty += th)
    for (int tx = -tw / 2; tx < SW; tx += tw) {
      assert_int_equal(ts_gis_lines_read(l, tx, ty, tw, th, tile, err), 0);
      for (int y = 0; y < th; y++)
        for (int x = 0; x < tw; x++) {
          int sx = tx + x, sy = ty + y;
          if (sx < 0 || sy < 0 || sx >= SW || sy >= SH) continue;
          if (tile[y * tw + x] != whole[sy * SW + sx])
            fail_msg("tile at %d,%d: pixel %d,%d is %d, the whole read's %d", tx, ty, sx, sy, tile[y * tw + x],
                     whole[sy * SW + sx]);
        }
    }
  free(tile);
  ts_gis_lines_close(l);
  free(whole);
  remove_dir();
}

/* Pixels where a and b differ, and line pixels of a. */
static void compare(const uint8_t *a, const uint8_t *b, long *differ, long *line) {
  *differ = *line = 0;
  for (int i = 0; i < SW * SH; i++) {
    *differ += a[i] != b[i];
    *line += a[i] != 0;
  }
}

/* Lon/lat (GeoJSON's WGS 84) on a UTM scene: reprojected, the same lines
 * to within rounding at the polygons' edges. */
static void lines_reprojected(void **state) {
  (void)state;
  make_dir();
  ts_gis_georef g;
  utm_georef(&g);
  write_geojson(in_dir("utm.geojson"), "EPSG::32632");
  write_geojson(in_dir("ll.geojson"), "EPSG::4326");
  int rp_utm, rp_ll;
  uint8_t *utm = read_lines(in_dir("utm.geojson"), &g, &rp_utm), *ll = read_lines(in_dir("ll.geojson"), &g, &rp_ll);
  assert_int_equal(rp_utm, 0);
  assert_int_equal(rp_ll, 1);
  long differ, line;
  compare(utm, ll, &differ, &line);
  if (differ * 1000 > line) fail_msg("%ld of %ld line pixels differ", differ, line);
  free(utm);
  free(ll);
  remove_dir();
}

/* A layer without CRS: in the scene's CRS it is placed there; in lon/lat
 * it misses the scene and is refused, both extents named; on a scene
 * without georeferencing its coordinates are pixels. */
static void lines_without_crs(void **state) {
  (void)state;
  make_dir();
  ts_gis_georef g;
  utm_georef(&g);
  write_geojson(in_dir("utm.geojson"), "EPSG::32632");
  write_shapefile(in_dir("utm.shp"), IN_UTM);
  write_shapefile(in_dir("ll.shp"), IN_LONLAT);
  write_shapefile(in_dir("px.shp"), IN_PIXELS);
  int rp;
  uint8_t *want = read_lines(in_dir("utm.geojson"), &g, &rp), *got = read_lines(in_dir("utm.shp"), &g, &rp);
  assert_int_equal(rp, 0);
  assert_memory_equal(want, got, SW * SH);
  free(want);
  free(got);
  /* On a scene without georeferencing, a layer without CRS is in pixels:
   * with widths in pixels, the same lines as in UTM on the UTM scene. */
  ts_gis_line_rules rules;
  test_rules(&rules);
  rules.width_field[0] = '\0';
  rules.rule[1].unit = TS_GIS_UNIT_PIXEL;
  want = read_lines_by(in_dir("utm.shp"), &g, &rules, &rp);
  got = read_lines_by(in_dir("px.shp"), NULL, &rules, &rp);
  assert_memory_equal(want, got, SW * SH);
  free(want);
  free(got);
  test_rules(&rules);
  char err[TS_ERR_LEN] = "";
  ts_gis_lines *l = (ts_gis_lines *)1;
  assert_int_equal(ts_gis_lines_open(in_dir("ll.shp"), &g, SW, SH, &rules, &l, err), TS_EFORMAT);
  assert_null(l);
  assert_non_null(strstr(err, "the layer has no CRS, so it was taken to be in the class map's"));
  if (strstr(err, "lies outside the scene's 500000,5700000..500128,5699904") == NULL) fail_msg("%s", err);
  remove_dir();
}

/* A layer in a CRS PROJ cannot relate to the scene's (a local site grid):
 * refused, both named. */
static void lines_without_transformation(void **state) {
  (void)state;
  make_dir();
  write_shapefile(in_dir("site.shp"), IN_UTM);
  FILE *f = fopen(in_dir("site.prj"), "w");
  assert_non_null(f);
  fputs("LOCAL_CS[\"site grid\",UNIT[\"metre\",1],AXIS[\"Easting\",EAST],AXIS[\"Northing\",NORTH]]", f);
  fclose(f);
  ts_gis_georef g;
  utm_georef(&g);
  ts_gis_line_rules rules;
  test_rules(&rules);
  char err[TS_ERR_LEN] = "";
  ts_gis_lines *l;
  assert_int_equal(ts_gis_lines_open(in_dir("site.shp"), &g, SW, SH, &rules, &l, err), TS_EFORMAT);
  if (strstr(err, "the layer is in site grid, the class map in WGS 84 / UTM zone 32N, and PROJ has no "
                  "transformation between them") == NULL || strstr(err, "ogr2ogr -t_srs") == NULL)
    fail_msg("%s", err);
  remove_dir();
}

static void lines_refused(void **state) {
  (void)state;
  make_dir();
  ts_gis_line_rules rules;
  test_rules(&rules);
  char err[TS_ERR_LEN] = "";
  ts_gis_lines *l;
  write_geojson(in_dir("utm.geojson"), "EPSG::32632");
  /* A layer with a CRS, a scene without one. */
  assert_int_equal(ts_gis_lines_open(in_dir("utm.geojson"), NULL, SW, SH, &rules, &l, err), TS_EFORMAT);
  assert_non_null(strstr(err, "the layer is in WGS 84 / UTM zone 32N but the class map has no CRS"));
  ts_gis_georef g;
  utm_georef(&g);
  /* No such file, field, layer; not a vector source. */
  assert_int_equal(ts_gis_lines_open(in_dir("none.geojson"), &g, SW, SH, &rules, &l, err), TS_ENOENT);
  assert_non_null(strstr(err, "none.geojson: no such file"));
  strcpy(rules.field, "type");
  assert_int_equal(ts_gis_lines_open(in_dir("utm.geojson"), &g, SW, SH, &rules, &l, err), TS_ENOENT);
  assert_non_null(strstr(err, "has no field \"type\" to choose the line rules by"));
  test_rules(&rules);
  strcpy(rules.layer, "rivers");
  assert_int_equal(ts_gis_lines_open(in_dir("utm.geojson"), &g, SW, SH, &rules, &l, err), TS_ENOENT);
  assert_non_null(strstr(err, "no layer \"rivers\" (it has 1)"));
  test_rules(&rules);
  strcpy(rules.width_field, "kind");
  assert_int_equal(ts_gis_lines_open(in_dir("utm.geojson"), &g, SW, SH, &rules, &l, err), TS_ENOENT);
  assert_non_null(strstr(err, "no numeric field \"kind\""));
  test_rules(&rules);
  make_raster(in_dir("r.tif"), 16, 16, 1, GDT_Byte, classes, 0, 0);
  assert_int_equal(ts_gis_lines_open(in_dir("r.tif"), &g, SW, SH, &rules, &l, err), TS_EFORMAT);
  assert_non_null(strstr(err, "not a vector source GDAL reads"));
  rules.rule[0].value = 0;
  assert_int_equal(ts_gis_lines_open(in_dir("utm.geojson"), &g, SW, SH, &rules, &l, err), TS_EINVAL);
  remove_dir();
}

/* One handle of each kind read from 4 threads at once, each its own tiles
 * (the tiled engine's tile jobs): every tile as the whole read has it. */
typedef struct {
  ts_gis_raster *r;
  ts_gis_lines *l;
  const uint16_t *ids;
  const uint8_t *lines;
  int first, bad;
} reader_job;

static void *read_tiles(void *arg) {
  reader_job *j = arg;
  char err[TS_ERR_LEN];
  uint16_t ids[64 * 48];
  uint8_t lines[64 * 48];
  for (int k = j->first; k < (SW / 64) * (SH / 48); k += 4) {
    int tx = k % (SW / 64) * 64, ty = k / (SW / 64) * 48;
    for (int rep = 0; rep < 5; rep++) {
      if (ts_gis_raster_read(j->r, tx, ty, 64, 48, ids, err) != 0 ||
          ts_gis_lines_read(j->l, tx, ty, 64, 48, lines, err) != 0)
        j->bad++;
      for (int y = 0; y < 48; y++)
        for (int x = 0; x < 64; x++)
          j->bad += ids[y * 64 + x] != j->ids[(ty + y) * SW + tx + x] ||
                    lines[y * 64 + x] != j->lines[(ty + y) * SW + tx + x];
    }
  }
  return NULL;
}

static void concurrent_reads(void **state) {
  (void)state;
  /* A cache of 1 MiB, so the threads decode and evict blocks all along
   * (GDAL reads the variable itself, at its first use in this process). */
  setenv("GDAL_CACHEMAX", "1", 1);
  make_dir();
  ts_gis_georef g;
  utm_georef(&g);
  make_raster(in_dir("classes.tif"), SW, SH, 1, GDT_UInt16, classes, 0, 0);
  write_geojson(in_dir("roads.geojson"), "EPSG::32632");
  int rp, w, h;
  uint8_t *lines = read_lines(in_dir("roads.geojson"), &g, &rp);
  char err[TS_ERR_LEN] = "";
  ts_gis_raster *r;
  assert_int_equal(ts_gis_raster_open(in_dir("classes.tif"), &r, &w, &h, NULL, err), 0);
  uint16_t *ids = malloc(SW * SH * 2);
  assert_int_equal(ts_gis_raster_read(r, 0, 0, SW, SH, ids, err), 0);
  ts_gis_line_rules rules;
  test_rules(&rules);
  ts_gis_lines *l;
  assert_int_equal(ts_gis_lines_open(in_dir("roads.geojson"), &g, SW, SH, &rules, &l, err), 0);
  pthread_t t[4];
  reader_job jobs[4];
  for (int i = 0; i < 4; i++) {
    jobs[i] = (reader_job){r, l, ids, lines, i, 0};
    assert_int_equal(pthread_create(&t[i], NULL, read_tiles, &jobs[i]), 0);
  }
  for (int i = 0; i < 4; i++) {
    pthread_join(t[i], NULL);
    assert_int_equal(jobs[i].bad, 0);
  }
  ts_gis_lines_close(l);
  ts_gis_raster_close(r);
  free(ids);
  free(lines);
  remove_dir();
}

/* --- the rules' JSON form ------------------------------------------------------ */

static void rules_parse(void **state) {
  (void)state;
  static const char text[] = "{\"layer\": \"roads\", \"field\": \"kind\", \"width_field\": \"width\",\n"
                             " \"rules\": [{\"match\": \"road\", \"value\": 255, \"width\": 6, \"order\": 2},\n"
                             "           {\"match\": \"path\", \"value\": 128, \"width\": 2, \"unit\": \"px\"}]}";
  ts_gis_line_rules r;
  char err[TS_ERR_LEN] = "";
  assert_int_equal(ts_gis_line_rules_parse(text, strlen(text), "cat.json", &r, err), 0);
  assert_string_equal(r.layer, "roads");
  assert_string_equal(r.field, "kind");
  assert_string_equal(r.width_field, "width");
  assert_int_equal(r.nrule, 2);
  assert_string_equal(r.rule[0].match, "road");
  assert_int_equal(r.rule[0].value, 255);
  assert_true(r.rule[0].width == 6 && r.rule[0].unit == TS_GIS_UNIT_MAP && r.rule[0].order == 2);
  assert_true(r.rule[1].width == 2 && r.rule[1].unit == TS_GIS_UNIT_PIXEL && r.rule[1].order == 0);
  assert_int_equal(r.rule[0].nhidden, 0);
  /* Without a field: one rule for every feature. */
  static const char one[] = "{\"rules\": [{\"value\": 9, \"width\": 1.5}]}";
  assert_int_equal(ts_gis_line_rules_parse(one, strlen(one), "cat.json", &r, err), 0);
  assert_int_equal(r.nrule, 1);
  assert_string_equal(r.rule[0].match, "");
}

/* Embedded in a catalogue's "lines" object, beside the catalogue's keys;
 * paths hidden under forest (1) and wetland (8), roads nowhere. */
static void rules_embedded_and_hidden(void **state) {
  (void)state;
  static const char text[] = "{\"lines\": {\"vector\": \"roads.geojson\", \"colours\": {\"128\": 100},\n"
                             "  \"field\": \"kind\", \"rules\": [\n"
                             "   {\"match\": \"road\", \"value\": 255, \"width\": 6},\n"
                             "   {\"match\": \"path\", \"value\": 128, \"width\": 2, \"hidden_under\": [1, 8]}]}}";
  ts_json_doc doc;
  char err[TS_ERR_LEN] = "";
  assert_int_equal(ts_json_parse(&doc, "cat.json", text, strlen(text), 1000, err), 0);
  int lines = ts_json_member(&doc, 0, "lines");
  static const char *const mine[] = {"vector", "colours", NULL};
  ts_gis_line_rules r;
  assert_int_equal(ts_gis_line_rules_read(&doc, lines, mine, &r, err), 0);
  assert_int_equal(r.nrule, 2);
  assert_int_equal(r.rule[1].nhidden, 2);
  assert_int_equal(r.rule[1].hidden_under[1], 8);
  /* Without the catalogue's keys declared, they are unknown. */
  assert_int_equal(ts_gis_line_rules_read(&doc, lines, NULL, &r, err), TS_EFORMAT);
  assert_string_equal(err, "cat.json:1:12: the line rules: unknown key \"vector\" (known: \"layer\", \"field\", "
                           "\"width_field\", \"rules\")");
  assert_int_equal(r.nrule, 0);
  ts_json_free(&doc);
  assert_int_equal(ts_gis_line_rules_parse(text + 11, strlen(text) - 12, "x", &r, err), TS_EFORMAT);
  /* Hiding: paths vanish over classes 1 and 8, roads stay everywhere. */
  assert_int_equal(ts_json_parse(&doc, "cat.json", text, strlen(text), 1000, err), 0);
  assert_int_equal(ts_gis_line_rules_read(&doc, lines, mine, &r, err), 0);
  ts_json_free(&doc);
  uint16_t ids[] = {1, 8, 2, 1, 8, 2, 1};
  uint8_t px[] = {128, 128, 128, 255, 255, 255, 0};
  ts_gis_lines_hide(&r, ids, px, 7);
  static const uint8_t want[] = {0, 0, 128, 255, 255, 255, 0};
  assert_memory_equal(px, want, 7);
}

static void rules_refused(void **state) {
  (void)state;
  static const struct {
    const char *text, *want;
  } bad[] = {
      {"[]", "cat.json:1:1: the line rules: must be an object, got an array"},
      {"{\"rules\": []}", "cat.json:1:11: the line rules: \"rules\" must be an array of 1..64 rules, got an array"},
      {"{\"feild\": \"kind\", \"rules\": []}", "cat.json:1:2: the line rules: unknown key \"feild\" (known: \"layer\", "
                                            "\"field\", \"width_field\", \"rules\")"},
      {"{\"rules\": [{\"value\": 1, \"width\": 1, \"colour\": 1}]}",
       "cat.json:1:37: line rule 1: unknown key \"colour\" (known: \"match\", \"value\", \"width\", \"unit\", \"order\", "
       "\"hidden_under\")"},
      {"{\"rules\": [{\"value\": 1, \"width\": 1}, {\"value\": 2, \"width\": 1}]}",
       "cat.json:1:11: the line rules: 2 rules but no \"field\" to choose between them: give one rule, or a field"},
      {"{\"rules\": [{\"match\": \"road\", \"value\": 1, \"width\": 1}]}",
       "cat.json:1:22: line rule 1: \"match\" needs a \"field\" to match against"},
      {"{\"field\": \"k\", \"rules\": [{\"value\": 1, \"width\": 1}]}", "cat.json:1:26: line rule 1: \"match\" is required"},
      {"{\"field\": \"k\", \"rules\": [{\"match\": \"a\", \"value\": 0, \"width\": 1}]}",
       "cat.json:1:50: line rule 1: \"value\" must be a whole number 1..255, got 0"},
      {"{\"field\": \"k\", \"rules\": [{\"match\": \"a\", \"value\": 1, \"width\": 0}]}",
       "cat.json:1:62: line rule 1: \"width\" must be above 0"},
      {"{\"field\": \"k\", \"rules\": [{\"match\": \"a\", \"value\": 1, \"width\": 1, \"unit\": \"m\"}]}",
       "cat.json:1:73: line rule 1: \"unit\" must be \"map\" (the CRS's units, metres for UTM) or \"px\", got \"m\""},
      {"{\"field\": \"k\", \"rules\": [{\"match\": \"a\", \"value\": 1, \"width\": 1}, {\"match\": \"a\", \"value\": 2, "
       "\"width\": 1}]}",
       "cat.json:1:76: line rule 2: \"match\" \"a\" is rule 1's too"},
      {"{\"field\": \"\", \"rules\": [{\"value\": 1, \"width\": 1}]}",
       "cat.json:1:11: the line rules: \"field\" must be a string of 1..63 bytes, got \"\""},
      {"{\"rules\": [{\"value\": 1, \"width\": 1, \"hidden_under\": [3, 3]}]}",
       "cat.json:1:57: line rule 1: class 3 is given twice"},
      {"{\"rules\": [{\"value\": 1, \"width\": 1, \"hidden_under\": [-1]}]}",
       "cat.json:1:54: line rule 1: \"hidden_under\" holds class ids, whole numbers 0..65535, got -1"},
      {"{\"rules\": [{\"value\": 1, \"width\": 1, \"order\": 0.5}]}",
       "cat.json:1:46: line rule 1: \"order\" must be a whole number -1000..1000, got 0.5"},
  };
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    ts_gis_line_rules r;
    char err[TS_ERR_LEN] = "";
    int rc = ts_gis_line_rules_parse(bad[i].text, strlen(bad[i].text), "cat.json", &r, err);
    if (rc != TS_EFORMAT || strcmp(err, bad[i].want) != 0)
      fail_msg("%s\n  gave %d \"%s\"\n  want \"%s\"", bad[i].text, rc, err, bad[i].want);
    assert_int_equal(r.nrule, 0);
  }
}

static void crs_definitions(void **state) {
  (void)state;
  char wkt[4096], err[TS_ERR_LEN] = "";
  assert_int_equal(ts_gis_crs_wkt("EPSG:32632", wkt, sizeof(wkt), err), 0);
  assert_non_null(strstr(wkt, "WGS 84 / UTM zone 32N"));
  assert_true(strncmp(wkt, "PROJCRS[", 8) == 0); /* WKT2 */
  /* WKT2 too long (1617 bytes), WKT1 fits (596): WKT1; neither: refused. */
  assert_int_equal(ts_gis_crs_wkt("EPSG:32632", wkt, 1000, err), 0);
  assert_true(strncmp(wkt, "PROJCS[\"WGS 84 / UTM zone 32N\"", 30) == 0);
  assert_int_equal(ts_gis_crs_wkt("EPSG:32632", wkt, 100, err), TS_ETOOBIG);
  assert_non_null(strstr(err, "EPSG:32632: its WKT takes 596 bytes, more than the 99 allowed"));
  assert_int_equal(ts_gis_crs_wkt("not a crs", wkt, sizeof(wkt), err), TS_EINVAL);
  assert_non_null(strstr(err, "not a crs is not a CRS GDAL knows"));
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(raster_byte),
    cmocka_unit_test(raster_int32),
    cmocka_unit_test(raster_bad_files),
    cmocka_unit_test(writer_round_trip),
    cmocka_unit_test(writer_cog),
    cmocka_unit_test(writer_bigtiff_when_needed),
    cmocka_unit_test(writer_abort_and_errors),
    cmocka_unit_test(lines_tiles_stitch_to_whole),
    cmocka_unit_test(lines_reprojected),
    cmocka_unit_test(lines_without_crs),
    cmocka_unit_test(lines_without_transformation),
    cmocka_unit_test(lines_refused),
    cmocka_unit_test(concurrent_reads),
    cmocka_unit_test(rules_parse),
    cmocka_unit_test(rules_embedded_and_hidden),
    cmocka_unit_test(rules_refused),
    cmocka_unit_test(crs_definitions),
};

TS_TEST_MAIN(tests)
