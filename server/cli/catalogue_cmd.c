/* catalogue_cmd.c - `texsyn catalogue --photo ORTHO --classes MAP -o
 * CAT.json`: the references of an aerial catalogue (catalogue.h) cut from
 * an orthophoto and its class map, so that a user with a GIS layer has a
 * catalogue in one command.
 *
 * Each class's reference is the largest *clean* rectangle of it: every
 * pixel of the class and at least --margin pixels from any other class
 * and from the photograph's edge (class maps and photographs never line
 * up to the pixel, and the pixels along a border mix both sides). The
 * clean pixels are the class's mask eroded by a (2m+1)² square, as two
 * running-window passes (rows, then columns); the largest rectangle of
 * them is the classic histogram sweep: per row, each column's run of
 * clean pixels up to it, and the largest rectangle under that histogram
 * with a stack; O(pixels) per class. Ties keep the first found (the
 * top-most, then left-most), so the same inputs give the same catalogue.
 *
 * Every class is checked before anything is written: one whose largest
 * clean rectangle is under --min-side on a side is named with what it got
 * and what to change. The catalogue written is read back with the
 * catalogue's own parser. */
#include "catalogue_cmd.h"

#include <getopt.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "catalogue.h"
#include "error.h"
#include "image.h"
#include "jobcmd.h"
#include "util.h"

static const char *const kUsage =
    "usage: texsyn catalogue --photo ORTHO --classes MAP -o CAT.json [options]\n"
    "\n"
    "Cuts an aerial catalogue (texsyn aerial --catalogue) from an orthophoto and\n"
    "its land-use class map: for every class in MAP, the largest rectangle of the\n"
    "photograph whose pixels are all of that class and at least --margin pixels\n"
    "from any other class and from the edge, written beside CAT.json as\n"
    "CAT-NAME.png; CAT.json names them, one class per value of MAP.\n"
    "\n"
    "  --photo ORTHO        the orthophoto (any format texsyn reads)\n"
    "  --classes MAP        its class map: one 8- or 16-bit channel, ORTHO's size;\n"
    "                       every value is a class (at most 64)\n"
    "  -o CAT.json          the catalogue to write\n"
    "  --margin M           clean pixels keep M pixels from other classes and the\n"
    "                       edge (0..256; default 4)\n"
    "  --min-side S         refuse a class whose rectangle is under SxS (8..4096;\n"
    "                       default 32)\n"
    "  --name ID=NAME       the name of class ID (default classID); repeatable\n"
    "  --structured ID      class ID is structured (settlement, industry), not\n"
    "                       stochastic (texsyn aerial --help); repeatable\n";

#define CAT_PATH 4096

typedef struct {
  const char *photo, *classes, *out;
  int margin, min_side;
  int nnames;
  int name_id[TS_CAT_MAX_CLASSES];
  const char *name[TS_CAT_MAX_CLASSES];
  int nstructured;
  int structured[TS_CAT_MAX_CLASSES];
} cat_opts;

typedef struct {
  int id, x, y, w, h;
  long pixels; /* of the class in the map */
  char name[TS_CAT_NAME_LEN];
} cat_class;

enum { OPT_PHOTO = 256, OPT_CLASSES, OPT_MARGIN, OPT_MIN_SIDE, OPT_NAME, OPT_STRUCTURED, OPT_HELP };

static int take_name(cat_opts *o, const char *arg, char *err) {
  const char *eq = strchr(arg, '=');
  char id[16];
  int v;
  if (eq == NULL || eq - arg >= (long)sizeof(id) || eq[1] == '\0')
    return ts_error(err, TS_EINVAL, "--name %s: need ID=NAME", arg);
  snprintf(id, sizeof(id), "%.*s", (int)(eq - arg), arg);
  if (ts_parse_int(id, 0, TS_CAT_MAX_ID, &v) != 0) return ts_error(err, TS_EINVAL, "--name %s: ID must be 0..%d", arg, TS_CAT_MAX_ID);
  if (strlen(eq + 1) >= TS_CAT_NAME_LEN) return ts_error(err, TS_EINVAL, "--name %s: at most %d bytes", arg, TS_CAT_NAME_LEN - 1);
  if (o->nnames == TS_CAT_MAX_CLASSES) return ts_error(err, TS_EINVAL, "--name: at most %d", TS_CAT_MAX_CLASSES);
  o->name_id[o->nnames] = v;
  o->name[o->nnames++] = eq + 1;
  return 0;
}

static int arg_int(const char *opt, const char *s, int lo, int hi, int *out, char *err) {
  long v;
  int rc = ts_arg_long(opt, s, lo, hi, &v, err);
  if (rc == 0) *out = (int)v;
  return rc;
}

static int take(cat_opts *o, int c, const char *arg, char *err) {
  int v;
  switch (c) {
  case OPT_PHOTO: o->photo = arg; return 0;
  case OPT_CLASSES: o->classes = arg; return 0;
  case 'o': o->out = arg; return 0;
  case OPT_MARGIN: return arg_int("--margin", arg, 0, 256, &o->margin, err);
  case OPT_MIN_SIDE: return arg_int("--min-side", arg, 8, 4096, &o->min_side, err);
  case OPT_NAME: return take_name(o, arg, err);
  case OPT_STRUCTURED:
    if (ts_parse_int(arg, 0, TS_CAT_MAX_ID, &v) != 0) return ts_error(err, TS_EINVAL, "--structured %s: an ID 0..%d", arg, TS_CAT_MAX_ID);
    if (o->nstructured == TS_CAT_MAX_CLASSES) return ts_error(err, TS_EINVAL, "--structured: at most %d", TS_CAT_MAX_CLASSES);
    o->structured[o->nstructured++] = v;
    return 0;
  default: return ts_error(err, TS_EINVAL, "unknown option or missing value (see texsyn catalogue --help)");
  }
}

static int parse(int argc, char **argv, cat_opts *o, char *err) {
  static const struct option opts[] = {
      {"photo", required_argument, 0, OPT_PHOTO},     {"classes", required_argument, 0, OPT_CLASSES},
      {"output", required_argument, 0, 'o'},          {"margin", required_argument, 0, OPT_MARGIN},
      {"min-side", required_argument, 0, OPT_MIN_SIDE}, {"name", required_argument, 0, OPT_NAME},
      {"structured", required_argument, 0, OPT_STRUCTURED}, {"help", no_argument, 0, OPT_HELP},
      {0, 0, 0, 0}};
  *o = (cat_opts){.margin = 4, .min_side = 32};
  optind = 1;
  opterr = 0;
  int c, rc = 0;
  while (rc == 0 && (c = getopt_long(argc, argv, "ho:", opts, NULL)) != -1) {
    if (c == 'h' || c == OPT_HELP) return 1;
    rc = take(o, c, optarg, err);
  }
  if (rc == 0 && optind < argc) rc = ts_error(err, TS_EINVAL, "unexpected argument '%s'", argv[optind]);
  if (rc == 0 && (o->photo == NULL || o->classes == NULL || o->out == NULL))
    rc = ts_error(err, TS_EINVAL, "--photo, --classes and -o are all required (see texsyn catalogue --help)");
  return rc;
}

/* ---- the map ----------------------------------------------------------- */

static int id_at(const ts_image *map, size_t i) {
  return map->type == TS_PIX_U8 ? ((const uint8_t *)map->pixels)[i] : ((const uint16_t *)map->pixels)[i];
}

static int check_inputs(const cat_opts *o, const ts_image *photo, const ts_image *map, char *err) {
  if (map->channels != 1 || (map->type != TS_PIX_U8 && map->type != TS_PIX_U16))
    return ts_error(err, TS_EINVAL, "--classes %s: need one 8- or 16-bit channel, not %d of %s", o->classes,
                    map->channels, ts_pixtype_name(map->type));
  if (map->width != photo->width || map->height != photo->height)
    return ts_error(err, TS_EINVAL, "--classes %s is %dx%d, --photo %s %dx%d: need one size", o->classes, map->width,
                    map->height, o->photo, photo->width, photo->height);
  return 0;
}

/* The classes present, by id, with their pixel counts: their number, or
 * TS_EINVAL past TS_CAT_MAX_CLASSES. */
static int classes_of(const cat_opts *o, const ts_image *map, cat_class *cls, char *err) {
  long *count = calloc(TS_CAT_MAX_ID + 1, sizeof(long));
  if (count == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  for (size_t i = 0; i < (size_t)map->width * (size_t)map->height; i++) count[id_at(map, i)]++;
  int n = 0;
  for (int id = 0; id <= TS_CAT_MAX_ID && n <= TS_CAT_MAX_CLASSES; id++)
    if (count[id] > 0 && n++ < TS_CAT_MAX_CLASSES) cls[n - 1] = (cat_class){.id = id, .pixels = count[id]};
  free(count);
  if (n > TS_CAT_MAX_CLASSES)
    return ts_error(err, TS_EINVAL, "--classes %s has more than %d class values: a catalogue holds at most %d",
                    o->classes, TS_CAT_MAX_CLASSES, TS_CAT_MAX_CLASSES);
  return n;
}

/* ---- the largest clean rectangle --------------------------------------- */

/* One running-window pass along lines of `len` cells `step` apart
 * (`stride` between lines): out = 1 where all 2m+1 cells around are 1
 * (cells past the ends count as 0). runs: len ints of scratch. */
static void erode_pass(const uint8_t *in, uint8_t *out, int lines, int len, size_t stride, size_t step, int m,
                       int *runs) {
  for (int l = 0; l < lines; l++) {
    const uint8_t *a = in + (size_t)l * stride;
    uint8_t *b = out + (size_t)l * stride;
    int run = 0; /* ones ending at the cell */
    for (int i = 0; i < len; i++) runs[i] = run = a[(size_t)i * step] ? run + 1 : 0;
    for (int i = 0; i < len; i++) b[(size_t)i * step] = i + m < len && i - m >= 0 && runs[i + m] >= 2 * m + 1;
  }
}

/* The largest rectangle of ones of a w x h mask into c's x, y, w, h,
 * top-most then left-most among equals. height: w ints, stack: w + 1. */
static void largest_rect(const uint8_t *mask, int w, int h, int *height, int *stack, cat_class *c) {
  long best = 0;
  memset(height, 0, sizeof(int) * (size_t)w);
  for (int y = 0; y < h; y++) {
    for (int x = 0; x < w; x++) height[x] = mask[(size_t)y * (size_t)w + (size_t)x] ? height[x] + 1 : 0;
    int top = 0;
    for (int x = 0; x <= w; x++) {
      int hx = x < w ? height[x] : 0;
      while (top > 0 && height[stack[top - 1]] >= hx) {
        int hh = height[stack[--top]], left = top > 0 ? stack[top - 1] + 1 : 0;
        long area = (long)hh * (long)(x - left);
        if (area > best) {
          best = area;
          c->x = left, c->y = y - hh + 1, c->w = x - left, c->h = hh;
        }
      }
      stack[top++] = x;
    }
  }
}

/* The class's clean rectangle into c (w = h = 0 when none). */
static int clean_rect(const ts_image *map, int margin, cat_class *c, char *err) {
  int w = map->width, h = map->height;
  size_t n = (size_t)w * (size_t)h;
  uint8_t *mask = malloc(n), *tmp = malloc(n);
  size_t side = (size_t)(w > h ? w : h) + 1;
  int *height = malloc(sizeof(int) * side), *stack = malloc(sizeof(int) * side);
  int rc = mask && tmp && height && stack ? 0 : ts_error(err, TS_ENOMEM, "out of memory for a %dx%d class map", w, h);
  if (rc == 0) {
    for (size_t i = 0; i < n; i++) mask[i] = id_at(map, i) == c->id;
    erode_pass(mask, tmp, h, w, (size_t)w, 1, margin, height); /* rows */
    erode_pass(tmp, mask, w, h, 1, (size_t)w, margin, height); /* columns */
    c->w = c->h = 0;
    largest_rect(mask, w, h, height, stack, c);
  }
  free(mask);
  free(tmp);
  free(height);
  free(stack);
  return rc;
}

/* ---- names, files and the catalogue ------------------------------------ */

static void name_classes(const cat_opts *o, cat_class *cls, int n) {
  for (int k = 0; k < n; k++) {
    snprintf(cls[k].name, sizeof(cls[k].name), "class%d", cls[k].id);
    for (int i = 0; i < o->nnames; i++)
      if (o->name_id[i] == cls[k].id) snprintf(cls[k].name, sizeof(cls[k].name), "%s", o->name[i]);
  }
}

static int is_structured(const cat_opts *o, int id) {
  for (int i = 0; i < o->nstructured; i++)
    if (o->structured[i] == id) return 1;
  return 0;
}

/* Every --name and --structured names a class of the map, names are
 * unique; every class has its rectangle: all problems at once, a line
 * each on stderr (one message would not hold 64 classes'). */
static int check_classes(const cat_opts *o, const cat_class *cls, int n, char *err) {
  char text[16384] = "";
  ts_problems pr = {text, sizeof(text), 0};
  for (int i = 0; i < o->nnames + o->nstructured; i++) {
    int id = i < o->nnames ? o->name_id[i] : o->structured[i - o->nnames], found = 0;
    for (int k = 0; k < n; k++) found |= cls[k].id == id;
    if (!found) ts_problems_add(&pr, "--%s %d: no pixel of MAP has that value", i < o->nnames ? "name" : "structured", id);
  }
  for (int a = 0; a < n; a++)
    for (int b = a + 1; b < n; b++)
      if (strcmp(cls[a].name, cls[b].name) == 0) ts_problems_add(&pr, "classes %d and %d are both named \"%s\"", cls[a].id, cls[b].id, cls[a].name);
  for (int k = 0; k < n; k++)
    if (cls[k].w < o->min_side || cls[k].h < o->min_side)
      ts_problems_add(&pr, "class %d (\"%s\", %ld pixels): its largest clean rectangle is %dx%d, under --min-side %d: "
                      "lower --margin (%d) or --min-side, or give a larger photograph", cls[k].id, cls[k].name,
                      cls[k].pixels, cls[k].w, cls[k].h, o->min_side, o->margin);
  if (pr.count == 0) return 0;
  for (char *line = strtok(text, "\n"); line != NULL; line = strtok(NULL, "\n")) fprintf(stderr, "texsyn catalogue: %s\n", line);
  return ts_error(err, TS_EINVAL, "nothing written (%d problem%s above)", pr.count, pr.count == 1 ? "" : "s");
}

/* The reference's file for class c beside the catalogue: CAT-NAME.png,
 * the name's bytes other than letters, digits, '-' and '_' as '_'. Its
 * path into path, its name as the catalogue gives it into rel. */
static int ref_file(const char *out, const cat_class *c, char *path, char *rel, char *err) {
  const char *slash = strrchr(out, '/'), *base = slash != NULL ? slash + 1 : out, *dot = strrchr(base, '.');
  int stem = dot != NULL && dot > base ? (int)(dot - base) : (int)strlen(base);
  char safe[TS_CAT_NAME_LEN];
  size_t k = 0;
  for (const char *p = c->name; *p != '\0' && k + 1 < sizeof(safe); p++) {
    char ch = *p;
    int ok = (ch >= 'a' && ch <= 'z') || (ch >= 'A' && ch <= 'Z') || (ch >= '0' && ch <= '9') || ch == '-' || ch == '_';
    safe[k++] = ok ? ch : '_';
  }
  safe[k] = '\0';
  int dir = slash != NULL ? (int)(base - out) : 0;
  if ((size_t)dir + (size_t)stem + strlen(safe) + 6 >= CAT_PATH)
    return ts_error(err, TS_EINVAL, "-o %s: the references' paths beside it would be too long", out);
  snprintf(rel, CAT_PATH, "%.*s-%s.png", stem, base, safe);
  memcpy(path, out, (size_t)dir);
  memcpy(path + dir, rel, strlen(rel) + 1);
  return 0;
}

static int write_crop(const ts_image *photo, const cat_class *c, const char *path, char *err) {
  ts_image crop;
  int rc = ts_image_alloc(&crop, c->w, c->h, photo->channels, photo->type, err);
  if (rc != 0) return rc;
  for (int y = 0; y < c->h; y++)
    for (int x = 0; x < c->w; x++) ts_image_copy_pixel(&crop, x, y, photo, c->x + x, c->y + y);
  rc = ts_image_write(path, &crop, NULL, err);
  ts_image_free(&crop);
  return rc;
}

/* A JSON string's body: the name's bytes, quotes and backslashes escaped
 * (names hold no control characters: catalogue.h). */
static void put_json_string(FILE *f, const char *s) {
  for (; *s != '\0'; s++) fprintf(f, *s == '"' || *s == '\\' ? "\\%c" : "%c", *s);
}

static int write_catalogue(const cat_opts *o, const ts_image *photo, const cat_class *cls, int n, char *err) {
  char tmp[TS_FILE_TMP_LEN];
  FILE *f = ts_file_create(o->out, tmp, err);
  if (f == NULL) return TS_EIO;
  int rc = 0;
  fprintf(f, "{\"classes\": [\n");
  for (int k = 0; rc == 0 && k < n; k++) {
    char path[CAT_PATH], rel[CAT_PATH];
    rc = ref_file(o->out, &cls[k], path, rel, err);
    if (rc == 0) rc = write_crop(photo, &cls[k], path, err);
    fprintf(f, "  {\"id\": %d, \"name\": \"", cls[k].id);
    put_json_string(f, cls[k].name);
    fprintf(f, "\", \"reference\": \"");
    put_json_string(f, rel);
    fprintf(f, "\", \"kind\": \"%s\"}%s\n", is_structured(o, cls[k].id) ? "structured" : "stochastic",
            k + 1 < n ? "," : "");
  }
  fprintf(f, "]}\n");
  return ts_file_commit(f, tmp, o->out, rc == 0, err) != 0 ? TS_EIO : rc;
}

static int run_catalogue(const cat_opts *o, char *err) {
  ts_image photo = {0}, map = {0};
  cat_class *cls = calloc(TS_CAT_MAX_CLASSES, sizeof(*cls));
  ts_catalogue *back = calloc(1, sizeof(*back));
  int rc = cls != NULL && back != NULL ? 0 : ts_error(err, TS_ENOMEM, "out of memory");
  if (rc == 0) rc = ts_image_read(o->photo, &photo, NULL, err);
  if (rc == 0) rc = ts_image_read(o->classes, &map, NULL, err);
  if (rc == 0) rc = check_inputs(o, &photo, &map, err);
  int n = rc == 0 ? classes_of(o, &map, cls, err) : 0;
  if (n < 0) rc = n;
  for (int k = 0; rc == 0 && k < n; k++) rc = clean_rect(&map, o->margin, &cls[k], err);
  if (rc == 0) name_classes(o, cls, n);
  if (rc == 0) rc = check_classes(o, cls, n, err);
  if (rc == 0) rc = write_catalogue(o, &photo, cls, n, err);
  if (rc == 0) rc = ts_catalogue_load(o->out, back, err); /* what texsyn aerial will read */
  for (int k = 0; rc == 0 && k < n; k++)
    printf("class %d (%s): %dx%d at (%d, %d), %.1f%% of its %ld pixels\n", cls[k].id, cls[k].name, cls[k].w,
           cls[k].h, cls[k].x, cls[k].y, 100.0 * cls[k].w * cls[k].h / (double)cls[k].pixels, cls[k].pixels);
  ts_image_free(&photo);
  ts_image_free(&map);
  free(cls);
  free(back);
  return rc;
}

int ts_cmd_catalogue(int argc, char **argv) {
  cat_opts o;
  char err[TS_ERR_LEN];
  int rc = parse(argc, argv, &o, err);
  if (rc == 1) {
    fputs(kUsage, stdout);
    return 0;
  }
  if (rc == 0) rc = run_catalogue(&o, err);
  if (rc != 0) fprintf(stderr, "texsyn catalogue: %s\n", err);
  return rc == 0 ? 0 : rc == TS_EINVAL ? 2 : 1;
}
