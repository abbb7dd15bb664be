/* aerial.c - `texsyn aerial --classes MAP --catalogue CAT.json -o OUT`:
 * a synthetic aerial image from a land-use class map (aerial_engine.c),
 * the catalogue (catalogue.h) naming each class's reference and the line
 * raster's colours. */
#include "aerial.h"

#include <errno.h>
#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "catalogue.h"
#include "error.h"
#include "fill.h"
#include "gis.h"
#include "jobcmd.h"
#include "paramopt.h"
#include "util.h"

static void usage(FILE *f, const ts_engine *e) {
  fprintf(f,
          "usage: texsyn aerial --classes MAP --catalogue CAT.json -o OUT [options]\n"
          "\n"
          "Builds a synthetic aerial image from a land-use map (Stahlhut 2004, ch. 5.1):\n"
          "MAP is a single-channel raster whose pixel values are class ids (a .tif is read\n"
          "through GDAL, other formats through OpenImageIO; a GeoTIFF keeps its\n"
          "georeferencing and CRS in OUT). The catalogue\n"
          "names each class's reference texture, its kind and usage weight, and\n"
          "optionally a line raster (roads, paths, rivers) and the colours its values\n"
          "are drawn in:\n"
          "\n"
          "  {\"classes\": [\n"
          "     {\"id\": 1, \"name\": \"forest\", \"reference\": \"forest.png\", \"kind\": \"stochastic\",\n"
          "      \"usage_weight\": 1.0},\n"
          "     {\"id\": 2, \"name\": \"town\", \"reference\": \"town.png\", \"kind\": \"structured\"}],\n"
          "   \"lines\": {\"raster\": \"roads.png\", \"colours\": {\"255\": [90, 90, 90]}}}\n"
          "\n"
          "or lines as a vector layer (GeoJSON, GeoPackage, Shapefile: any OGR reads),\n"
          "rasterised at the scene's grid by rules giving each feature's line value,\n"
          "width and draw order, and the classes a line is hidden under:\n"
          "\n"
          "   \"lines\": {\"vector\": \"roads.geojson\", \"field\": \"kind\", \"width_field\": \"width\",\n"
          "     \"rules\": [{\"match\": \"road\", \"value\": 255, \"width\": 6, \"unit\": \"map\", \"order\": 2},\n"
          "               {\"match\": \"path\", \"value\": 128, \"width\": 2, \"unit\": \"px\",\n"
          "                \"hidden_under\": [1]}],\n"
          "     \"colours\": {\"255\": [90, 90, 90], \"128\": [150, 130, 100]}}\n"
          "\n"
          "A layer in another CRS than MAP's is reprojected into MAP's (refused when PROJ\n"
          "has no transformation); a layer without a CRS is taken to be in MAP's; a layer\n"
          "lying outside the scene is refused.\n"
          "\n"
          "Paths are relative to the catalogue. Lines are drawn first; then each class is\n"
          "filled by constrained MRF synthesis from its own reference, stochastic classes\n"
          "first, structured after, level by level: every class sees the lines and the\n"
          "classes filled before it, and matches them at its edges. The output is 8-bit\n"
          "RGB at MAP's size. Exact: the same bytes in-process and on any pool.\n"
          "\n"
          "Scenes of any size: the scene is cut into --tile tiles, made in four phases\n"
          "(a 2x2 checkerboard) so each joins its finished neighbours through a --halo;\n"
          "MAP is read by regions and OUT written band by band (TIFF and OpenEXR tiled),\n"
          "so memory follows three rows of tiles, not the scene. A .tif OUT is a tiled\n"
          "DEFLATE GeoTIFF written through GDAL (BigTIFF when large), a Cloud-Optimised\n"
          "GeoTIFF with --cog; EXR, PNG and JPEG through OpenImageIO. A scene OUT's file\n"
          "system may lack room for (its pixels uncompressed) is refused before any work.\n"
          "\n"
          "  --classes MAP        the class map\n"
          "  --catalogue F        the catalogue (JSON, as above)\n");
  ts_paramopt_help(f, e);
  fprintf(f, "%s", ts_job_options_help);
}

enum { OPT_CLASSES = TS_OPT_OWN, OPT_CATALOGUE };

/* Its own options: the inputs (the parameters are the engine's). */
static const struct option own_opts[] = {
    {"classes", required_argument, 0, OPT_CLASSES}, {"catalogue", required_argument, 0, OPT_CATALOGUE},
    TS_JOB_LONGOPTS, {0, 0, 0, 0}};

typedef struct {
  ts_job_cmd job;
  const char *catalogue;
  ts_catalogue *cat;
  char pack_dir[64];    /* "": none; else holds the layer as one file */
  char packed[4096 + 64];
} aerial_opts;

static int option(void *ctx, int c, const char *arg, int argc, char **argv, char *err) {
  (void)argc, (void)argv, (void)err;
  aerial_opts *o = ctx;
  switch (c) {
  case OPT_CLASSES: o->job.in[0] = arg; return 0;
  case OPT_CATALOGUE: o->catalogue = arg; return 0;
  default: return TS_ENOENT;
  }
}

/* The catalogue as spec keys and inputs: a reference per class, in its
 * order, then the line raster. */
static int take_catalogue(aerial_opts *o, char *err) {
  const ts_catalogue *cat = o->cat;
  int max = TS_ENGINE_MAX_INPUTS - (cat->line_vector ? 3 : 2); /* the map, the lines, the rules */
  if (cat->nclass > max)
    return ts_error(err, TS_EINVAL, "%s: %d classes; texsyn aerial takes at most %d", o->catalogue, cat->nclass, max);
  char key[32], value[160];
  snprintf(value, sizeof(value), "%d", cat->nclass);
  int rc = ts_job_set_key(&o->job, "classes", value, "classes", err);
  for (int k = 0; rc == 0 && k < cat->nclass; k++) {
    const ts_cat_class *c = &cat->cls[k];
    snprintf(key, sizeof(key), "class%d", k + 1);
    snprintf(value, sizeof(value), "%d %s %.17g %s", c->id, ts_cat_kind_name(c->kind), c->usage_weight, c->name);
    rc = ts_job_set_key(&o->job, key, value, "class", err);
    o->job.in[1 + k] = c->reference;
  }
  if (rc != 0 || !cat->has_lines) return rc;
  snprintf(value, sizeof(value), "%d", cat->ncolours);
  rc = ts_job_set_key(&o->job, "lines", "1", "lines", err);
  if (rc == 0 && cat->line_vector) rc = ts_job_set_key(&o->job, "vector", "1", "lines", err);
  if (rc == 0) rc = ts_job_set_key(&o->job, "colours", value, "colours", err);
  for (int k = 0; rc == 0 && k < cat->ncolours; k++) {
    const ts_cat_colour *c = &cat->colour[k];
    snprintf(key, sizeof(key), "colour%d", k + 1);
    snprintf(value, sizeof(value), "%u %u %u %u", c->value, c->rgb[0], c->rgb[1], c->rgb[2]);
    rc = ts_job_set_key(&o->job, key, value, "colour", err);
  }
  o->job.in[1 + cat->nclass] = cat->line_raster;
  if (cat->line_vector) o->job.in[2 + cat->nclass] = o->catalogue; /* the engine reads the rules from it */
  return rc;
}

static int parse(int argc, char **argv, aerial_opts *o, char *err) {
  ts_job_cmd_init(&o->job, "aerial", ts_engine_find("aerial"));
  static const ts_cmd_options cmd = {"o:h", own_opts, option, usage};
  int rc = ts_paramopt_parse(&o->job, &cmd, o, argc, argv, err);
  if (rc != 0) return rc;
  if (o->job.in[0] == NULL || o->catalogue == NULL)
    return ts_error(err, TS_EINVAL, "--classes MAP and --catalogue F are both required (see texsyn aerial --help)");
  rc = ts_catalogue_load(o->catalogue, o->cat, err);
  if (rc == 0) rc = take_catalogue(o, err);
  return rc != 0 ? rc : ts_job_parse_end(&o->job, err);
}

/* A vector layer sent to a coordinator goes as one file: a Shapefile and
 * its side files as one GeoPackage made in a temporary directory
 * (ts_gis_vector_single); a one-file source as it is. */
static int pack_layer(aerial_opts *o, char *err) {
  const ts_catalogue *cat = o->cat;
  if (o->job.server == NULL || !cat->line_vector) return 0;
  const char *tmp = getenv("TMPDIR");
  snprintf(o->pack_dir, sizeof(o->pack_dir), "%.40s/texsyn-XXXXXX", tmp != NULL && tmp[0] ? tmp : "/tmp");
  if (mkdtemp(o->pack_dir) == NULL) {
    int rc = ts_error(err, TS_EIO, "cannot make a directory in %s to pack %s: %s (set TMPDIR)",
                      tmp != NULL && tmp[0] ? tmp : "/tmp", cat->line_raster, strerror(errno));
    o->pack_dir[0] = '\0';
    return rc;
  }
  int rc = ts_gis_vector_single(cat->line_raster, o->pack_dir, o->packed, sizeof(o->packed), err);
  if (rc == 0) o->job.in[1 + cat->nclass] = o->packed;
  return rc;
}

static void unpack_layer(aerial_opts *o) {
  if (o->pack_dir[0] == '\0') return;
  if (strcmp(o->packed, o->cat->line_raster) != 0) unlink(o->packed);
  rmdir(o->pack_dir);
}

int ts_cmd_aerial(int argc, char **argv) {
  char err[TS_ERR_LEN] = "";
  aerial_opts *o = calloc(1, sizeof(*o));
  ts_catalogue *cat = calloc(1, sizeof(*cat)); /* ~270 KB of paths */
  if (o == NULL || cat == NULL) {
    free(o);
    free(cat);
    fprintf(stderr, "texsyn aerial: out of memory\n");
    return 1;
  }
  o->cat = cat;
  int status = 2;
  if (parse(argc, argv, o, err) != 0 || pack_layer(o, err) != 0) fprintf(stderr, "texsyn aerial: %s\n", err);
  else status = ts_job_run(&o->job);
  unpack_layer(o);
  free(cat);
  free(o);
  return status;
}
