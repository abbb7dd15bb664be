/* image_check.c - see image_check.h. */
#include "image_check.h"

#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>

#include "error.h"

#define HEAD_LEN 8          /* bytes that tell the format */
#define NAME_MAX_LEN 256    /* an OpenEXR attribute or type name is shorter */
#define SHOWN_MAX 40        /* file bytes shown in a message */
#define SHOWN_LEN (4 * SHOWN_MAX + 4)

/* Opens path ourselves first: OpenImageIO reports a missing file, a
 * directory and a permission problem all as "could not open". Reads the
 * first bytes on the way. */
static int check_file(const char *path, uint8_t head[HEAD_LEN], size_t *n, char *err) {
  int fd = open(path, O_RDONLY | O_NONBLOCK);
  if (fd < 0) {
    if (errno == ENOENT || errno == ENOTDIR) return ts_error(err, TS_ENOENT, "%s: no such file", path);
    return ts_error(err, TS_EIO, "%s: %s", path, strerror(errno));
  }
  struct stat st;
  int rc = fstat(fd, &st);
  if (rc == 0 && !S_ISREG(st.st_mode)) {
    close(fd);
    return ts_error(err, TS_EFORMAT, "%s: not a regular file", path);
  }
  ssize_t k = pread(fd, head, HEAD_LEN, 0);
  int e = errno;
  close(fd);
  if (k < 0) return ts_error(err, TS_EIO, "%s: %s", path, strerror(e));
  *n = (size_t)k;
  return 0;
}

static int read_head(const ts_image_src *src, uint8_t head[HEAD_LEN], size_t *n, char *err) {
  if (src->path != NULL) return check_file(src->path, head, n, err);
  *n = src->len < HEAD_LEN ? src->len : HEAD_LEN;
  if (*n > 0) memcpy(head, src->data, *n);
  return 0;
}

/* The reader for a file starting with these bytes, or NULL for anything
 * but the four supported formats. */
static const char *format_of(const uint8_t *head, size_t n) {
  static const struct {
    const char *format;
    uint8_t len;
    uint8_t magic[HEAD_LEN];
  } kMagic[] = {
      {"png", 8, {0x89, 'P', 'N', 'G', 0x0d, 0x0a, 0x1a, 0x0a}},
      {"jpeg", 3, {0xff, 0xd8, 0xff}},
      {"tiff", 4, {'I', 'I', 42, 0}}, /* classic, little- and big-endian */
      {"tiff", 4, {'M', 'M', 0, 42}},
      {"tiff", 4, {'I', 'I', 43, 0}}, /* BigTIFF */
      {"tiff", 4, {'M', 'M', 0, 43}},
      {"openexr", 4, {0x76, 0x2f, 0x31, 0x01}},
  };
  for (size_t i = 0; i < sizeof(kMagic) / sizeof(kMagic[0]); i++)
    if (n >= kMagic[i].len && memcmp(head, kMagic[i].magic, kMagic[i].len) == 0) return kMagic[i].format;
  return NULL;
}

int ts_image_sniff(const ts_image_src *src, const char **format, char *err) {
  uint8_t head[HEAD_LEN];
  size_t n = 0;
  int rc = read_head(src, head, &n, err);
  if (rc != 0) return rc;
  if (n == 0) return ts_error(err, TS_EFORMAT, "%s: empty file (0 bytes), not an image", src->name);
  *format = format_of(head, n);
  if (*format != NULL) return 0;
  char hex[3 * HEAD_LEN + 1] = "";
  for (size_t i = 0, k = 0; i < n; i++, k = strlen(hex))
    snprintf(hex + k, sizeof(hex) - k, "%s%02x", i ? " " : "", head[i]);
  return ts_error(err, TS_EFORMAT, "%s: not a PNG, JPEG, TIFF or OpenEXR image (starts with bytes %s)",
                  src->name, hex);
}

FILE *ts_image_src_open(const ts_image_src *src) {
  /* fmemopen only reads here; the cast is what its prototype wants. */
  return src->path != NULL ? fopen(src->path, "rb") : fmemopen((void *)src->data, src->len, "rb");
}

/* File bytes fit for a one-line message: printable ASCII as is, the rest
 * as \xNN, at most SHOWN_MAX bytes shown. */
static void shown(const uint8_t *raw, size_t n, char out[SHOWN_LEN]) {
  size_t k = 0;
  for (size_t i = 0; i < n && i < SHOWN_MAX; i++) {
    uint8_t c = raw[i];
    if (c >= 0x20 && c < 0x7f && c != '\\')
      out[k++] = (char)c;
    else
      k += (size_t)snprintf(out + k, SHOWN_LEN - k, "\\x%02x", c);
  }
  snprintf(out + k, SHOWN_LEN - k, "%s", n > SHOWN_MAX ? "..." : "");
}

/* libpng allocates (and this build touches) a text chunk at the length
 * the file claims: 322 bytes claiming a 1.8 GB tEXt took 1.9 GB of memory
 * (found by fuzz_image). Every chunk length is checked against the bytes
 * left first, up to IEND. 1 if they fit; 0 with why set, or left as the
 * caller's when the file cannot be read. */
static int png_sizes_ok(FILE *f, char *why, size_t cap) {
  if (fseeko(f, 0, SEEK_END) != 0) return 0;
  off_t end = ftello(f);
  if (end < 8 || fseeko(f, 8, SEEK_SET) != 0) return 0;
  for (off_t pos = 8; pos < end;) {
    uint8_t h[8];
    if (end - pos < 12 || fread(h, 1, 8, f) != 8) {
      snprintf(why, cap, "file ends inside a chunk header");
      return 0;
    }
    uint32_t len = (uint32_t)h[0] << 24 | (uint32_t)h[1] << 16 | (uint32_t)h[2] << 8 | h[3];
    if (len > 0x7fffffffu || (off_t)len > end - pos - 12) {
      char type[SHOWN_LEN];
      shown(h + 4, 4, type);
      snprintf(why, cap, "chunk '%s' claims %" PRIu32 " bytes, the file has %lld left", type, len,
               (long long)(end - pos - 12));
      return 0;
    }
    if (memcmp(h + 4, "IEND", 4) == 0) return 1;
    pos += 12 + (off_t)len;
    if (fseeko(f, pos, SEEK_SET) != 0) return 0;
  }
  snprintf(why, cap, "no IEND chunk");
  return 0;
}

/* A NUL-terminated OpenEXR header string into s (not terminated there):
 * its length, or -1 with why set. */
static int exr_string(FILE *f, char s[NAME_MAX_LEN], char *why, size_t cap) {
  size_t n = 0;
  int c;
  while ((c = fgetc(f)) > 0 && n < NAME_MAX_LEN) s[n++] = (char)c;
  if (c < 0 || n >= NAME_MAX_LEN) {
    snprintf(why, cap, "%s", c < 0 ? "header cut short" : "header attribute name over 255 bytes");
    return -1;
  }
  return (int)n;
}

/* Skips one header attribute: name, type name, int32 size, value. 1 if
 * skipped, 0 at the empty name that ends a header, -1 if the size is more
 * than the file holds or the file cannot be read (why set, or left as the
 * caller's). */
static int exr_attr(FILE *f, off_t end, char *why, size_t cap) {
  char name[NAME_MAX_LEN], type[NAME_MAX_LEN];
  int n = exr_string(f, name, why, cap);
  if (n <= 0) return n;
  if (exr_string(f, type, why, cap) < 0) return -1;
  uint8_t b[4];
  if (fread(b, 1, 4, f) != 4) {
    snprintf(why, cap, "header cut short");
    return -1;
  }
  int64_t size = (int32_t)(b[0] | b[1] << 8 | b[2] << 16 | (uint32_t)b[3] << 24);
  off_t here = ftello(f);
  if (size < 0 || here < 0 || size > end - here) {
    char text[SHOWN_LEN];
    shown((const uint8_t *)name, (size_t)n, text);
    snprintf(why, cap, "header attribute '%s' claims %lld bytes, more than the file holds", text,
             (long long)size);
    return -1;
  }
  return fseeko(f, (off_t)size, SEEK_CUR) == 0 ? 1 : -1;
}

/* OpenEXR 3.1 allocates every header attribute at the size the file
 * claims before reading it (found by fuzz_image: a 707-byte file asking
 * for 1.2 GB), so the attribute sizes are checked against the bytes the
 * file has first, through every header of a multi-part file. 1 if they
 * fit; 0 with why set, or left as the caller's. */
static int exr_sizes_ok(FILE *f, char *why, size_t cap) {
  if (fseeko(f, 0, SEEK_END) != 0) return 0;
  off_t end = ftello(f);
  uint8_t v[4];
  if (end < 8 || fseeko(f, 4, SEEK_SET) != 0 || fread(v, 1, 4, f) != 4) {
    snprintf(why, cap, "header cut short");
    return 0;
  }
  int multipart = (v[1] & 0x10) != 0; /* version flag bit 12 */
  for (int headers = 0;; headers++) {
    int attrs = 0, rc;
    while ((rc = exr_attr(f, end, why, cap)) == 1) attrs++;
    if (rc < 0) return 0;
    if (attrs == 0 && headers > 0) return 1; /* the empty header ends the list */
    if (!multipart) return 1;
  }
}

int ts_image_check_sizes(const ts_image_src *src, const char *format, char *err) {
  int exr = strcmp(format, "openexr") == 0;
  if (!exr && strcmp(format, "png") != 0) return 0;
  char why[TS_ERR_LEN];
  snprintf(why, sizeof(why), "%s", exr ? "cannot read the header" : "cannot read the chunks");
  FILE *f = ts_image_src_open(src);
  int ok = f != NULL && (exr ? exr_sizes_ok(f, why, sizeof(why)) : png_sizes_ok(f, why, sizeof(why)));
  if (f != NULL) fclose(f);
  if (ok) return 0;
  if (exr) return ts_error(err, TS_EFORMAT, "%s: not a readable openexr image: %s", src->name, why);
  return ts_error(err, TS_EFORMAT, "%s: unreadable or truncated image: %s", src->name, why);
}
