/* gis_lines.c - gis.h's vector lines rasterised by region.
 *
 * At open, every feature the rules take is read once, brought into the
 * scene's CRS (reprojected when the layer's differs: gis.h says what is
 * decided for each pair of CRSs and why), then into the scene's pixel
 * space (x right, y down, one unit a pixel) with the inverse geotransform,
 * and buffered there to half its width: the buffered polygons, their
 * envelopes and values are all that is kept, the size of the vector data.
 *
 * A read burns the polygons whose envelope meets the region into a MEM
 * dataset of the region's size whose geotransform is (x, 1, 0, y, 0, 1):
 * GDAL maps a vertex to the region's pixels by subtracting the region's
 * integer origin, exact in floating point, and burns the pixels whose
 * centre lies inside a polygon, so a region reads what the same area of a
 * whole-scene rasterisation holds (tests/unit/test_gis.c stitches tiles
 * and compares). Polygons are burnt in draw order, a later one over an
 * earlier one. */
#include <cpl_conv.h>
#include <cpl_error.h>
#include <gdal_alg.h>
#include <math.h>
#include <ogr_api.h>
#include <ogr_srs_api.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "error.h"
#include "gis_gdal.h"

typedef struct {
  OGRGeometryH geom;          /* buffered, in the scene's pixel space */
  double x0, y0, x1, y1;      /* its envelope */
  double value;
  int order, rule;
  long seq;                   /* the feature's place in the layer */
} line_item;

struct ts_gis_lines {
  pthread_mutex_t lock;
  line_item *item;
  int n, cap;
  int reprojected;
  char path[4096];
};

/* What opening needs along the way. */
typedef struct {
  const char *path;
  const ts_gis_line_rules *rules;
  int width, height;
  double inv[6];                  /* map -> scene pixel */
  double px_size;                 /* map units per pixel */
  OGRCoordinateTransformationH ct; /* layer CRS -> scene CRS, or NULL */
  int field, width_field;         /* field indexes, -1 for none */
} opening;

static int check_rules(const char *path, const ts_gis_line_rules *r, char *err) {
  if (r == NULL || r->nrule < 1 || r->nrule > TS_GIS_MAX_RULES)
    return ts_error(err, TS_EINVAL, "%s: need 1..%d line rules", path, TS_GIS_MAX_RULES);
  if (r->field[0] == '\0' && r->nrule != 1)
    return ts_error(err, TS_EINVAL, "%s: %d line rules but no field to choose between them", path, r->nrule);
  for (int i = 0; i < r->nrule; i++) {
    const ts_gis_line_rule *u = &r->rule[i];
    int unit_ok = u->unit == TS_GIS_UNIT_MAP || u->unit == TS_GIS_UNIT_PIXEL;
    if (u->value == 0 || !(u->width > 0 && u->width <= 1e4) || !unit_ok)
      return ts_error(err, TS_EINVAL, "%s: line rule %d: need a value 1..255, a width in (0, 10000], a unit", path,
                      i + 1);
  }
  return 0;
}

/* The CRSs' short names for messages. */
static const char *crs_name(OGRSpatialReferenceH s) {
  const char *n = s != NULL ? OSRGetName(s) : NULL;
  return n != NULL ? n : "an unnamed CRS";
}

/* Decides how the layer's coordinates reach the scene's CRS (gis.h). */
static int plan_crs(opening *o, OGRLayerH layer, const ts_gis_georef *scene, int *no_crs, char *err) {
  OGRSpatialReferenceH ls = OGR_L_GetSpatialRef(layer);
  *no_crs = ls == NULL;
  if (ls == NULL) return 0;
  if (scene == NULL || scene->crs_wkt[0] == '\0')
    return ts_error(err, TS_EFORMAT, "%s: the layer is in %s but the class map has no CRS, so it cannot be placed: "
                    "georeference the class map or give a layer without a CRS in its pixel or map coordinates",
                    o->path, crs_name(ls));
  OGRSpatialReferenceH ss = OSRNewSpatialReference(scene->crs_wkt);
  if (ss == NULL)
    return ts_error(err, TS_EFORMAT, "%s: the class map's CRS is not one GDAL understands: %s", o->path,
                    ts_gis_last_error());
  int rc = 0;
  if (!OSRIsSame(ls, ss)) {
    OGRSpatialReferenceH from = OSRClone(ls);
    OSRSetAxisMappingStrategy(from, OAMS_TRADITIONAL_GIS_ORDER);
    OSRSetAxisMappingStrategy(ss, OAMS_TRADITIONAL_GIS_ORDER);
    CPLErrorReset();
    o->ct = OCTNewCoordinateTransformation(from, ss);
    if (o->ct == NULL)
      rc = ts_error(err, TS_EFORMAT, "%s: the layer is in %s, the class map in %s, and PROJ has no transformation "
                    "between them (%s): reproject the layer (ogr2ogr -t_srs)", o->path, crs_name(ls), crs_name(ss),
                    ts_gis_last_error());
    OSRDestroySpatialReference(from);
  }
  OSRDestroySpatialReference(ss);
  return rc;
}

/* Map coordinates to the scene's pixels, every vertex in place. */
static void to_pixels(OGRGeometryH g, const double inv[6]) {
  int parts = OGR_G_GetGeometryCount(g);
  for (int i = 0; i < parts; i++) to_pixels(OGR_G_GetGeometryRef(g, i), inv);
  if (parts > 0) return;
  int n = OGR_G_GetPointCount(g);
  for (int i = 0; i < n; i++) {
    double x = OGR_G_GetX(g, i), y = OGR_G_GetY(g, i);
    OGR_G_SetPoint_2D(g, i, inv[0] + x * inv[1] + y * inv[2], inv[3] + x * inv[4] + y * inv[5]);
  }
}

/* The rule feature f takes, or -1. */
static int rule_of(const opening *o, OGRFeatureH f) {
  if (o->field < 0) return 0;
  if (!OGR_F_IsFieldSetAndNotNull(f, o->field)) return -1;
  const char *v = OGR_F_GetFieldAsString(f, o->field);
  for (int i = 0; i < o->rules->nrule; i++)
    if (strcmp(o->rules->rule[i].match, v) == 0) return i;
  return -1;
}

/* The half width of feature f under rule u, in pixels. */
static double half_width(const opening *o, OGRFeatureH f, const ts_gis_line_rule *u) {
  double w = u->width;
  if (o->width_field >= 0 && OGR_F_IsFieldSetAndNotNull(f, o->width_field)) {
    double fw = OGR_F_GetFieldAsDouble(f, o->width_field);
    if (fw > 0 && fw <= 1e4) w = fw;
  }
  return (u->unit == TS_GIS_UNIT_PIXEL ? w : w / o->px_size) / 2;
}

static int add_item(ts_gis_lines *l, line_item it) {
  if (l->n == l->cap) {
    int cap = l->cap ? 2 * l->cap : 256;
    line_item *p = realloc(l->item, (size_t)cap * sizeof(*p));
    if (p == NULL) return TS_ENOMEM;
    l->item = p;
    l->cap = cap;
  }
  l->item[l->n++] = it;
  return 0;
}

/* Feature f (number seq) into l, if a rule takes it. */
static int take_feature(ts_gis_lines *l, const opening *o, OGRFeatureH f, long seq, char *err) {
  int r = rule_of(o, f);
  OGRGeometryH g0 = OGR_F_GetGeometryRef(f);
  if (r < 0 || g0 == NULL || OGR_G_IsEmpty(g0)) return 0;
  OGRGeometryH g = OGR_G_Clone(g0);
  if (g == NULL) return ts_error(err, TS_ENOMEM, "%s: out of memory", o->path);
  OGR_G_FlattenTo2D(g);
  CPLErrorReset();
  if (o->ct != NULL && OGR_G_Transform(g, o->ct) != OGRERR_NONE) {
    OGR_G_DestroyGeometry(g);
    return ts_error(err, TS_EFORMAT, "%s: feature %lld does not reproject into the class map's CRS (%s): is the "
                    "layer's CRS right?", o->path, (long long)OGR_F_GetFID(f), ts_gis_last_error());
  }
  to_pixels(g, o->inv);
  const ts_gis_line_rule *u = &o->rules->rule[r];
  OGRGeometryH b = OGR_G_Buffer(g, half_width(o, f, u), 8);
  OGR_G_DestroyGeometry(g);
  if (b == NULL)
    return ts_error(err, TS_EFORMAT, "%s: feature %lld cannot be buffered to its width: %s", o->path,
                    (long long)OGR_F_GetFID(f), ts_gis_last_error());
  OGREnvelope e;
  OGR_G_GetEnvelope(b, &e);
  line_item it = {b, e.MinX, e.MinY, e.MaxX, e.MaxY, u->value, u->order, r, seq};
  if (add_item(l, it) != 0) {
    OGR_G_DestroyGeometry(b);
    return ts_error(err, TS_ENOMEM, "%s: out of memory", o->path);
  }
  return 0;
}

static int by_draw_order(const void *a, const void *b) {
  const line_item *p = a, *q = b;
  if (p->order != q->order) return p->order < q->order ? -1 : 1;
  if (p->rule != q->rule) return p->rule < q->rule ? -1 : 1;
  return p->seq < q->seq ? -1 : p->seq > q->seq;
}

/* A layer whose lines all miss the scene is refused, both extents named
 * (gis.h): without a CRS it was most likely in another one; with one, it
 * is the wrong layer or the wrong scene, and an empty line raster would
 * hide that. The extent is the layer's own, in its own CRS. */
static int check_inside(const ts_gis_lines *l, const opening *o, OGRLayerH layer, const ts_gis_georef *scene,
                        int no_crs, char *err) {
  for (int i = 0; i < l->n; i++)
    if (l->item[i].x1 > 0 && l->item[i].x0 < o->width && l->item[i].y1 > 0 && l->item[i].y0 < o->height) return 0;
  if (l->n == 0) return 0;
  OGREnvelope e = {0};
  OGR_L_GetExtent(layer, &e, TRUE);
  const double *t = scene != NULL && scene->has_geo ? scene->transform : NULL;
  double sx0 = t ? t[0] : 0, sy0 = t ? t[3] : 0;
  double sx1 = t ? t[0] + o->width * t[1] + o->height * t[2] : o->width;
  double sy1 = t ? t[3] + o->width * t[4] + o->height * t[5] : o->height;
  if (!no_crs)
    return ts_error(err, TS_EFORMAT,
                    "%s: no line of the layer (extent %.10g,%.10g..%.10g,%.10g in its CRS) crosses the scene "
                    "%.10g,%.10g..%.10g,%.10g: is it the layer of this class map?",
                    o->path, e.MinX, e.MinY, e.MaxX, e.MaxY, sx0, sy0, sx1, sy1);
  return ts_error(err, TS_EFORMAT,
                  "%s: the layer has no CRS, so it was taken to be in the class map's, but its extent "
                  "%.10g,%.10g..%.10g,%.10g lies outside the scene's %.10g,%.10g..%.10g,%.10g: give the layer "
                  "its CRS (a .prj, or ogr2ogr -a_srs)",
                  o->path, e.MinX, e.MinY, e.MaxX, e.MaxY, sx0, sy0, sx1, sy1);
}

/* Finds the layer and the rules' fields. */
static int find_layer(opening *o, GDALDatasetH ds, OGRLayerH *out, char *err) {
  const ts_gis_line_rules *r = o->rules;
  OGRLayerH layer = r->layer[0] != '\0' ? GDALDatasetGetLayerByName(ds, r->layer)
                                        : GDALDatasetGetLayerCount(ds) > 0 ? GDALDatasetGetLayer(ds, 0) : NULL;
  if (layer == NULL)
    return ts_error(err, TS_ENOENT, "%s: no layer %s%s%s (it has %d): name one it holds (ogrinfo lists them)",
                    o->path, r->layer[0] ? "\"" : "", r->layer[0] ? r->layer : "at all", r->layer[0] ? "\"" : "",
                    GDALDatasetGetLayerCount(ds));
  OGRFeatureDefnH def = OGR_L_GetLayerDefn(layer);
  o->field = r->field[0] != '\0' ? OGR_FD_GetFieldIndex(def, r->field) : -1;
  if (r->field[0] != '\0' && o->field < 0)
    return ts_error(err, TS_ENOENT, "%s: layer %s has no field \"%s\" to choose the line rules by", o->path,
                    OGR_L_GetName(layer), r->field);
  o->width_field = r->width_field[0] != '\0' ? OGR_FD_GetFieldIndex(def, r->width_field) : -1;
  if (r->width_field[0] != '\0') {
    OGRFieldType t = o->width_field >= 0 ? OGR_Fld_GetType(OGR_FD_GetFieldDefn(def, o->width_field)) : OFTString;
    if (t != OFTInteger && t != OFTInteger64 && t != OFTReal)
      return ts_error(err, TS_ENOENT, "%s: layer %s has no numeric field \"%s\" for the lines' widths", o->path,
                      OGR_L_GetName(layer), r->width_field);
  }
  *out = layer;
  return 0;
}

/* The scene's pixel <-> map affine and pixel size. */
static int plan_grid(opening *o, const ts_gis_georef *scene, char *err) {
  double id[6] = {0, 1, 0, 0, 0, 1}, gt[6];
  memcpy(gt, scene != NULL && scene->has_geo ? scene->transform : id, sizeof(gt));
  double det = gt[1] * gt[5] - gt[2] * gt[4];
  if (!GDALInvGeoTransform(gt, o->inv) || !(fabs(det) > 0))
    return ts_error(err, TS_EINVAL, "%s: the class map's geotransform has no inverse (a pixel of zero size)",
                    o->path);
  o->px_size = sqrt(fabs(det));
  return 0;
}

static int read_features(ts_gis_lines *l, opening *o, OGRLayerH layer, char *err) {
  OGR_L_ResetReading(layer);
  OGRFeatureH f;
  long seq = 0;
  int rc = 0;
  CPLErrorReset();
  while (rc == 0 && (f = OGR_L_GetNextFeature(layer)) != NULL) {
    rc = take_feature(l, o, f, seq++, err);
    OGR_F_Destroy(f);
  }
  if (rc == 0 && CPLGetLastErrorType() >= CE_Failure)
    rc = ts_error(err, TS_EFORMAT, "%s: reading its features failed: %s", o->path, ts_gis_last_error());
  return rc;
}

int ts_gis_lines_open(const char *path, const ts_gis_georef *scene, int width, int height,
                      const ts_gis_line_rules *rules, ts_gis_lines **out, char *err) {
  *out = NULL;
  ts_gis_init();
  struct stat st;
  if (stat(path, &st) != 0) return ts_error(err, TS_ENOENT, "%s: no such file: give the vector layer's path", path);
  if (strlen(path) >= sizeof(((ts_gis_lines *)0)->path))
    return ts_error(err, TS_EINVAL, "%s: the path is too long", path);
  if (width <= 0 || height <= 0) return ts_error(err, TS_EINVAL, "%s: scene size %dx%d", path, width, height);
  opening o = {.path = path, .rules = rules, .width = width, .height = height};
  int rc = check_rules(path, rules, err);
  if (rc == 0) rc = plan_grid(&o, scene, err);
  if (rc != 0) return rc;
  CPLErrorReset();
  GDALDatasetH ds = GDALOpenEx(path, GDAL_OF_VECTOR | GDAL_OF_READONLY, NULL, NULL, NULL);
  if (ds == NULL)
    return ts_error(err, TS_EFORMAT, "%s: not a vector source GDAL reads (%s)", path, ts_gis_last_error());
  ts_gis_lines *l = calloc(1, sizeof(*l));
  OGRLayerH layer = NULL;
  int no_crs = 0;
  if (l == NULL) rc = ts_error(err, TS_ENOMEM, "%s: out of memory", path);
  if (rc == 0) rc = find_layer(&o, ds, &layer, err);
  if (rc == 0) rc = plan_crs(&o, layer, scene, &no_crs, err);
  if (rc == 0) {
    pthread_mutex_init(&l->lock, NULL);
    strcpy(l->path, path);
    l->reprojected = o.ct != NULL;
    rc = read_features(l, &o, layer, err);
  }
  if (rc == 0) rc = check_inside(l, &o, layer, scene, no_crs, err);
  if (o.ct != NULL) OCTDestroyCoordinateTransformation(o.ct);
  GDALClose(ds);
  if (rc != 0) {
    if (l != NULL && l->path[0] != '\0') ts_gis_lines_close(l);
    else free(l);
    return rc;
  }
  qsort(l->item, (size_t)l->n, sizeof(*l->item), by_draw_order);
  *out = l;
  return 0;
}

/* Burns the items meeting the region into a MEM dataset of its size. */
static int burn(ts_gis_lines *l, int x, int y, int w, int h, uint8_t *dst, char *err) {
  OGRGeometryH *geoms = malloc((size_t)(l->n ? l->n : 1) * sizeof(*geoms));
  double *values = malloc((size_t)(l->n ? l->n : 1) * sizeof(*values));
  int n = 0, rc = 0;
  if (geoms == NULL || values == NULL) rc = ts_error(err, TS_ENOMEM, "%s: out of memory", l->path);
  for (int i = 0; rc == 0 && i < l->n; i++) {
    const line_item *it = &l->item[i];
    if (it->x1 < x || it->x0 > (double)x + w || it->y1 < y || it->y0 > (double)y + h) continue;
    geoms[n] = it->geom;
    values[n++] = it->value;
  }
  if (rc == 0 && n > 0) {
    GDALDriverH mem = GDALGetDriverByName("MEM");
    CPLErrorReset();
    GDALDatasetH ds = mem != NULL ? GDALCreate(mem, "", w, h, 1, GDT_Byte, NULL) : NULL;
    double gt[6] = {x, 1, 0, y, 0, 1};
    int band = 1;
    if (ds == NULL)
      rc = ts_error(err, TS_ENOMEM, "%s: no memory for a %dx%d region: %s", l->path, w, h, ts_gis_last_error());
    else if (GDALSetGeoTransform(ds, gt) != CE_None ||
             GDALRasterizeGeometries(ds, 1, &band, n, geoms, NULL, NULL, values, NULL, NULL, NULL) != CE_None ||
             GDALDatasetRasterIO(ds, GF_Read, 0, 0, w, h, dst, w, h, GDT_Byte, 1, NULL, 1, w, 1) != CE_None)
      rc = ts_error(err, TS_EIO, "%s: rasterising %dx%d at %d,%d failed: %s", l->path, w, h, x, y,
                    ts_gis_last_error());
    if (ds != NULL) GDALClose(ds);
  }
  free(geoms);
  free(values);
  return rc;
}

int ts_gis_lines_read(ts_gis_lines *l, int x, int y, int w, int h, uint8_t *dst, char *err) {
  int rc = ts_gis_check_region(l->path, x, y, w, h, err);
  if (rc != 0) return rc;
  memset(dst, 0, (size_t)w * h);
  pthread_mutex_lock(&l->lock);
  rc = burn(l, x, y, w, h, dst, err);
  pthread_mutex_unlock(&l->lock);
  return rc;
}

void ts_gis_lines_info(const ts_gis_lines *l, int *nfeatures, int *reprojected) {
  if (nfeatures != NULL) *nfeatures = l->n;
  if (reprojected != NULL) *reprojected = l->reprojected;
}

void ts_gis_lines_close(ts_gis_lines *l) {
  if (l == NULL) return;
  for (int i = 0; i < l->n; i++) OGR_G_DestroyGeometry(l->item[i].geom);
  free(l->item);
  pthread_mutex_destroy(&l->lock);
  free(l);
}
