/* image_oiio.cpp - image files through OpenImageIO; see image.h.
 *
 * The only C++ in texsyn: a thin shim that keeps OpenImageIO's types and
 * exceptions on this side of an extern "C" boundary. Every entry point
 * catches everything and answers with a TS_E* code and one line in err.
 *
 * Reads take a file or a file's bytes in memory (through OpenImageIO's
 * IOMemReader, bounds-checked); both go through ts_open and ts_read, so a reference the
 * coordinator probes at submit and reads later is checked the same way.
 * The reader is picked from the first bytes among PNG, JPEG, TIFF and
 * OpenEXR only: OpenImageIO would otherwise try every plugin it has
 * (FFmpeg, DICOM, camera raw, ...) on whatever a client sends.
 *
 * Three things OpenImageIO 2.4 does not do for us, handled here:
 *  - A failed read is not always a false return: libtiff strip errors and
 *    libjpeg's "premature end of file" leave read_image() true with a
 *    pending error. Any pending error after a read fails it, so a truncated
 *    file never yields a partially grey image.
 *  - Its per-thread global error message outlives the call that set it; we
 *    clear it on entry and exit so one call's failure never shows in the
 *    next call's message.
 *  - It neither reads nor writes GeoTIFF tags. We read the raw tags from
 *    the first TIFF directory into the metadata and, when writing a TIFF,
 *    append them to the file OpenImageIO wrote (see "GeoTIFF" below). */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <memory>
#include <new>
#include <string>
#include <vector>

#include <OpenImageIO/filesystem.h>
#include <OpenImageIO/imageio.h>
#include <OpenImageIO/strutil.h>

extern "C" {
#include "error.h"
#include "image.h"
}
#include "image_meta.h"

using OIIO::ImageInput;
using OIIO::ImageOutput;
using OIIO::ImageSpec;
using OIIO::ParamValue;
using OIIO::ParamValueList;
using OIIO::TypeDesc;

struct ts_meta {
  ParamValueList attribs;
};

/* --- small helpers ------------------------------------------------------- */

/* OpenImageIO messages can span lines; err holds one. */
static std::string ts_oneline(std::string s) {
  for (char &ch : s)
    if (ch == '\n' || ch == '\r') ch = ' ';
  while (!s.empty() && s.back() == ' ') s.pop_back();
  return s.empty() ? std::string("no reason given") : s;
}

/* Clears OpenImageIO's per-thread global error on entry and on exit. */
struct ts_oiio_errscope {
  ts_oiio_errscope() { OIIO::geterror(); }
  ~ts_oiio_errscope() {
    try {
      OIIO::geterror();
    } catch (...) {
    }
  }
};

static TypeDesc ts_oiio_type(ts_pixtype t) {
  switch (t) {
  case TS_PIX_U8:
    return TypeDesc::UINT8;
  case TS_PIX_U16:
    return TypeDesc::UINT16;
  case TS_PIX_F16:
    return TypeDesc::HALF;
  case TS_PIX_F32:
    break;
  }
  return TypeDesc::FLOAT;
}

/* The type an image is kept in: the file's own for uint8, uint16, half and
 * float; float for anything else (int8, int16, uint32, double, ...), which
 * OpenImageIO scales to [0, 1] ([-1, 1] for signed) as usual. */
static ts_pixtype ts_kept_type(TypeDesc t) {
  switch (t.basetype) {
  case TypeDesc::UINT8:
    return TS_PIX_U8;
  case TypeDesc::UINT16:
    return TS_PIX_U16;
  case TypeDesc::HALF:
    return TS_PIX_F16;
  default:
    return TS_PIX_F32;
  }
}

/* Channels of different types (EXR half colour with float depth, ...) share
 * the narrowest type that holds all of them exactly. */
static ts_pixtype ts_spec_type(const ImageSpec &spec) {
  if (spec.channelformats.empty()) return ts_kept_type(spec.format);
  ts_pixtype t = ts_kept_type(spec.channelformats[0]);
  for (TypeDesc cf : spec.channelformats) {
    ts_pixtype u = ts_kept_type(cf);
    if (u == t) continue;
    bool ints = (t == TS_PIX_U8 || t == TS_PIX_U16) && (u == TS_PIX_U8 || u == TS_PIX_U16);
    t = ints ? TS_PIX_U16 : TS_PIX_F32;
  }
  return t;
}

/* --- GeoTIFF ------------------------------------------------------------- *
 *
 * The georeferencing of a GeoTIFF lives in six private TIFF tags (plus two
 * GDAL ones for metadata and nodata). We keep them verbatim, as typed
 * attributes, never decoding the GeoKey directory: passing the raw tags on
 * is what keeps every key, known to us or not, intact.
 *
 * Writing appends the values and a copy of the first directory with these
 * entries added to the end of the file OpenImageIO wrote, then points the
 * header at the new directory. Nothing already written moves, so every
 * offset in the old entries stays valid; the old directory (a few hundred
 * bytes) becomes unreferenced. Both byte orders and BigTIFF are handled. */

enum { TS_TIFF_ASCII = 2, TS_TIFF_SHORT = 3, TS_TIFF_DOUBLE = 12 };

struct ts_geotag {
  uint16_t tag, type;
  const char *name;
};

static const ts_geotag kGeoTags[] = {
    {33550, TS_TIFF_DOUBLE, "GeoTIFF:ModelPixelScale"},
    {33922, TS_TIFF_DOUBLE, "GeoTIFF:ModelTiePoint"},
    {34264, TS_TIFF_DOUBLE, "GeoTIFF:ModelTransformation"},
    {34735, TS_TIFF_SHORT, "GeoTIFF:GeoKeyDirectory"},
    {34736, TS_TIFF_DOUBLE, "GeoTIFF:GeoDoubleParams"},
    {34737, TS_TIFF_ASCII, "GeoTIFF:GeoAsciiParams"},
    {42112, TS_TIFF_ASCII, "GDAL:Metadata"},
    {42113, TS_TIFF_ASCII, "GDAL:NoData"},
};

/* Sanity bounds: a directory or a tag larger than this is corrupt. */
static const uint64_t kTiffMaxEntries = 4096;
static const uint64_t kTiffMaxValues = 1u << 20;

static const ts_geotag *ts_geotag_find(uint64_t tag) {
  for (const ts_geotag &g : kGeoTags)
    if (g.tag == tag) return &g;
  return nullptr;
}

static bool ts_is_geo_attr(const std::string &name) {
  for (const ts_geotag &g : kGeoTags)
    if (OIIO::Strutil::iequals(name, g.name)) return true;
  return false;
}

struct ts_file_closer {
  void operator()(FILE *f) const { fclose(f); }
};
typedef std::unique_ptr<FILE, ts_file_closer> ts_file;

/* An open TIFF: byte order ("MM" is big-endian), BigTIFF or classic, the
 * file size and the offset of the first directory. */
struct ts_tiff {
  FILE *f;
  bool be, big;
  uint64_t size, ifd;
  int word() const { return big ? 8 : 4; }    /* count and offset width */
  int entry() const { return big ? 20 : 12; } /* directory entry size */
};

static uint64_t ts_tiff_get(const ts_tiff &t, const uint8_t *p, int n) {
  uint64_t v = 0;
  for (int i = 0; i < n; i++) v |= (uint64_t)p[t.be ? n - 1 - i : i] << (8 * i);
  return v;
}

static void ts_tiff_put(const ts_tiff &t, uint8_t *p, int n, uint64_t v) {
  for (int i = 0; i < n; i++) p[t.be ? n - 1 - i : i] = (uint8_t)(v >> (8 * i));
}

static bool ts_tiff_pread(const ts_tiff &t, uint64_t off, void *buf, uint64_t n) {
  return off <= t.size && n <= t.size - off && fseeko(t.f, (off_t)off, SEEK_SET) == 0 &&
         fread(buf, 1, n, t.f) == n;
}

static bool ts_tiff_pwrite(const ts_tiff &t, uint64_t off, const void *buf, size_t n) {
  return fseeko(t.f, (off_t)off, SEEK_SET) == 0 && fwrite(buf, 1, n, t.f) == n;
}

static bool ts_tiff_open(ts_tiff &t, FILE *f) {
  uint8_t h[16];
  t.f = f;
  if (fseeko(f, 0, SEEK_END) != 0) return false;
  off_t end = ftello(f);
  if (end < 0) return false;
  t.size = (uint64_t)end;
  if (!ts_tiff_pread(t, 0, h, 8)) return false;
  if (h[0] == 'I' && h[1] == 'I')
    t.be = false;
  else if (h[0] == 'M' && h[1] == 'M')
    t.be = true;
  else
    return false;
  uint64_t magic = ts_tiff_get(t, h + 2, 2);
  t.big = magic == 43;
  if (magic == 42) {
    t.ifd = ts_tiff_get(t, h + 4, 4);
    return true;
  }
  if (!t.big || !ts_tiff_pread(t, 0, h, 16) || ts_tiff_get(t, h + 4, 2) != 8 ||
      ts_tiff_get(t, h + 6, 2) != 0)
    return false;
  t.ifd = ts_tiff_get(t, h + 8, 8);
  return true;
}

/* The first directory's raw entries and its next-directory offset. */
struct ts_tiff_dir {
  std::vector<uint8_t> entries;
  uint64_t next;
};

static bool ts_tiff_read_dir(const ts_tiff &t, ts_tiff_dir &d) {
  int cw = t.big ? 8 : 2; /* entry count width */
  uint8_t b[8];
  if (!ts_tiff_pread(t, t.ifd, b, cw)) return false;
  uint64_t n = ts_tiff_get(t, b, cw);
  if (n == 0 || n > kTiffMaxEntries) return false;
  d.entries.resize(n * t.entry());
  if (!ts_tiff_pread(t, t.ifd + cw, d.entries.data(), d.entries.size()) ||
      !ts_tiff_pread(t, t.ifd + cw + d.entries.size(), b, t.word()))
    return false;
  d.next = ts_tiff_get(t, b, t.word());
  return true;
}

/* Values of the entry at e, tsize bytes each, inline or at their offset. */
static bool ts_tiff_values(const ts_tiff &t, const uint8_t *e, int tsize,
                           std::vector<uint8_t> &out) {
  uint64_t count = ts_tiff_get(t, e + 4, t.word());
  if (count == 0 || count > kTiffMaxValues) return false;
  const uint8_t *field = e + 4 + t.word();
  out.resize(count * tsize);
  if (out.size() <= (size_t)t.word()) {
    memcpy(out.data(), field, out.size());
    return true;
  }
  return ts_tiff_pread(t, ts_tiff_get(t, field, t.word()), out.data(), out.size());
}

static void ts_geo_add(const ts_tiff &t, const ts_geotag &g, const std::vector<uint8_t> &v,
                       ParamValueList &attrs) {
  if (g.type == TS_TIFF_ASCII) {
    std::string s(v.begin(), v.end());
    while (!s.empty() && s.back() == '\0') s.pop_back();
    attrs.add_or_replace(ParamValue(g.name, OIIO::string_view(s)));
    return;
  }
  if (g.type == TS_TIFF_SHORT) {
    std::vector<uint16_t> s(v.size() / 2);
    for (size_t i = 0; i < s.size(); i++) s[i] = (uint16_t)ts_tiff_get(t, &v[2 * i], 2);
    attrs.add_or_replace(
        ParamValue(g.name, TypeDesc(TypeDesc::UINT16, (int)s.size()), 1, s.data()));
    return;
  }
  std::vector<double> d(v.size() / 8);
  for (size_t i = 0; i < d.size(); i++) {
    uint64_t bits = ts_tiff_get(t, &v[8 * i], 8);
    memcpy(&d[i], &bits, 8);
  }
  attrs.add_or_replace(ParamValue(g.name, TypeDesc(TypeDesc::DOUBLE, (int)d.size()), 1, d.data()));
}

/* Adds the GeoTIFF tags of the first directory of the TIFF in f (a file,
 * or fmemopen'ed bytes) to attrs. A malformed tag is skipped, not an
 * error: the pixels are still good. */
static void ts_geo_read(ts_file f, ParamValueList &attrs) {
  ts_tiff t;
  ts_tiff_dir d;
  if (!f || !ts_tiff_open(t, f.get()) || !ts_tiff_read_dir(t, d)) return;
  std::vector<uint8_t> v;
  for (size_t off = 0; off < d.entries.size(); off += t.entry()) {
    const uint8_t *e = &d.entries[off];
    const ts_geotag *g = ts_geotag_find(ts_tiff_get(t, e, 2));
    if (g == nullptr || ts_tiff_get(t, e + 2, 2) != g->type) continue;
    int tsize = g->type == TS_TIFF_DOUBLE ? 8 : g->type == TS_TIFF_SHORT ? 2 : 1;
    if (ts_tiff_values(t, e, tsize, v)) ts_geo_add(t, *g, v, attrs);
  }
}

/* One entry to add: its tag, type, count and values in file byte order. */
struct ts_geo_entry {
  const ts_geotag *g;
  uint64_t count;
  std::vector<uint8_t> data;
};

/* The GeoTIFF attributes of attrs serialised for file t. Attributes of the
 * wrong type (not from a GeoTIFF) are left out. */
static std::vector<ts_geo_entry> ts_geo_collect(const ts_tiff &t, const ParamValueList &attrs) {
  std::vector<ts_geo_entry> out;
  for (const ts_geotag &g : kGeoTags) {
    auto p = attrs.find(g.name, TypeDesc::UNKNOWN, false);
    if (p == attrs.end()) continue;
    ts_geo_entry e{&g, 0, {}};
    TypeDesc ty = p->type();
    size_t n = ty.basevalues() * (size_t)p->nvalues();
    if (g.type == TS_TIFF_ASCII && ty == OIIO::TypeString && n == 1) {
      std::string s = p->get_string();
      e.data.assign(s.begin(), s.end());
      e.data.push_back('\0');
    } else if (g.type == TS_TIFF_SHORT && ty.basetype == TypeDesc::UINT16) {
      const uint16_t *s = (const uint16_t *)p->data();
      e.data.resize(2 * n);
      for (size_t i = 0; i < n; i++) ts_tiff_put(t, &e.data[2 * i], 2, s[i]);
    } else if (g.type == TS_TIFF_DOUBLE && ty.basetype == TypeDesc::DOUBLE) {
      const double *s = (const double *)p->data();
      e.data.resize(8 * n);
      for (size_t i = 0; i < n; i++) {
        uint64_t bits;
        memcpy(&bits, &s[i], 8);
        ts_tiff_put(t, &e.data[8 * i], 8, bits);
      }
    } else {
      continue;
    }
    e.count = g.type == TS_TIFF_ASCII ? e.data.size() : n;
    if (e.count == 0 || e.count > kTiffMaxValues) continue;
    out.push_back(std::move(e));
  }
  return out;
}

static bool ts_has_geo(const ParamValueList &attrs) {
  for (const ParamValue &p : attrs)
    if (ts_is_geo_attr(p.name().string())) return true;
  return false;
}

/* Appends attrs' GeoTIFF tags to the TIFF at path (see above). */
static bool ts_geo_write(const char *path, const ParamValueList &attrs, std::string &why) {
  ts_file f(fopen(path, "r+b"));
  ts_tiff t;
  ts_tiff_dir d;
  if (!f) {
    why = strerror(errno);
    return false;
  }
  if (!ts_tiff_open(t, f.get()) || !ts_tiff_read_dir(t, d)) {
    why = "cannot parse the TIFF directory to add GeoTIFF tags";
    return false;
  }
  std::vector<ts_geo_entry> geo = ts_geo_collect(t, attrs);
  /* Old entries minus any of ours, then ours; sorted by tag as TIFF wants. */
  std::vector<std::vector<uint8_t>> entries;
  for (size_t off = 0; off < d.entries.size(); off += t.entry())
    if (ts_geotag_find(ts_tiff_get(t, &d.entries[off], 2)) == nullptr)
      entries.emplace_back(d.entries.begin() + off, d.entries.begin() + off + t.entry());
  uint64_t pos = (t.size + 7) & ~(uint64_t)7; /* word-aligned append */
  static const uint8_t zeros[8] = {0};
  bool ok = ts_tiff_pwrite(t, t.size, zeros, pos - t.size);
  for (const ts_geo_entry &g : geo) {
    std::vector<uint8_t> e(t.entry(), 0);
    ts_tiff_put(t, &e[0], 2, g.g->tag);
    ts_tiff_put(t, &e[2], 2, g.g->type);
    ts_tiff_put(t, &e[4], t.word(), g.count);
    if (g.data.size() <= (size_t)t.word()) {
      memcpy(&e[4 + t.word()], g.data.data(), g.data.size());
    } else {
      ts_tiff_put(t, &e[4 + t.word()], t.word(), pos);
      ok = ok && ts_tiff_pwrite(t, pos, g.data.data(), g.data.size());
      uint64_t end = pos + g.data.size();
      pos = (end + 7) & ~(uint64_t)7;
      ok = ok && ts_tiff_pwrite(t, end, zeros, pos - end);
    }
    entries.push_back(std::move(e));
  }
  std::sort(entries.begin(), entries.end(),
            [&t](const std::vector<uint8_t> &a, const std::vector<uint8_t> &b) {
              return ts_tiff_get(t, a.data(), 2) < ts_tiff_get(t, b.data(), 2);
            });
  int cw = t.big ? 8 : 2;
  std::vector<uint8_t> dir(cw + entries.size() * t.entry() + t.word());
  ts_tiff_put(t, dir.data(), cw, entries.size());
  for (size_t i = 0; i < entries.size(); i++)
    memcpy(&dir[cw + i * t.entry()], entries[i].data(), t.entry());
  ts_tiff_put(t, &dir[dir.size() - t.word()], t.word(), d.next);
  if (!t.big && pos + dir.size() > UINT32_MAX) {
    why = "GeoTIFF tags would push the file past the 4 GiB classic TIFF limit";
    return false;
  }
  uint8_t head[8];
  ts_tiff_put(t, head, t.word(), pos);
  ok = ok && ts_tiff_pwrite(t, pos, dir.data(), dir.size()) &&
       ts_tiff_pwrite(t, t.big ? 8 : 4, head, t.word());
  if (!ok || fclose(f.release()) != 0) {
    why = strerror(errno);
    return false;
  }
  return true;
}

/* --- metadata ------------------------------------------------------------ */

/* Whether a source attribute is passed on to an output. Dropped: whatever
 * describes how the source was encoded rather than what the image is
 * (compression, strip and tile layout, bit depth, JPEG subsampling,
 * OpenImageIO's reader notes, EXIF pixel dimensions, thumbnails), which
 * the target format and our own defaults decide; and the GeoTIFF tags,
 * which only TIFF outputs get, written by ts_geo_write. Kept: everything
 * else, e.g. resolution, ICC profile, colour space, EXIF/IPTC, captions. */
static bool ts_meta_passes(const std::string &name) {
  static const char *const keep[] = {"oiio:ColorSpace", "oiio:Gamma"};
  static const char *const drop_prefix[] = {
      "oiio:", "tiff:", "png:", "jpeg:", "openexr:", "thumbnail_"};
  static const char *const drop[] = {"compression",          "CompressionQuality",
                                     "planarconfig",         "textureformat",
                                     "Exif:PixelXDimension", "Exif:PixelYDimension"};
  for (const char *k : keep)
    if (OIIO::Strutil::iequals(name, k)) return true;
  for (const char *p : drop_prefix)
    if (OIIO::Strutil::istarts_with(name, p)) return false;
  for (const char *d : drop)
    if (OIIO::Strutil::iequals(name, d)) return false;
  return !ts_is_geo_attr(name);
}

/* --- read ---------------------------------------------------------------- */

/* Frees a partly built image unless released (errors and exceptions). */
struct ts_image_holder {
  ts_image img = {};
  ~ts_image_holder() { ts_image_free(&img); }
};

/* Where an image comes from: a file, or a file's bytes in memory. Messages
 * call it name. */
struct ts_source {
  const char *name;
  const char *path; /* nullptr: the bytes are data[0, len) */
  const uint8_t *data;
  size_t len;
};

/* The first bytes of a file, enough to tell the format. */
struct ts_head {
  uint8_t b[8];
  size_t n;
};

/* Opens path ourselves first: OpenImageIO reports a missing file, a
 * directory and a permission problem all as "could not open". Reads the
 * first bytes on the way. */
static int ts_check_file(const char *path, ts_head &head, char *err) {
  int fd = open(path, O_RDONLY | O_NONBLOCK);
  if (fd < 0) {
    if (errno == ENOENT || errno == ENOTDIR)
      return ts_error(err, TS_ENOENT, "%s: no such file", path);
    return ts_error(err, TS_EIO, "%s: %s", path, strerror(errno));
  }
  struct stat st;
  int rc = fstat(fd, &st);
  if (rc == 0 && !S_ISREG(st.st_mode)) {
    close(fd);
    return ts_error(err, TS_EFORMAT, "%s: not a regular file", path);
  }
  ssize_t n = pread(fd, head.b, sizeof(head.b), 0);
  int e = errno;
  close(fd);
  if (n < 0) return ts_error(err, TS_EIO, "%s: %s", path, strerror(e));
  head.n = (size_t)n;
  return 0;
}

static int ts_source_head(const ts_source &src, ts_head &head, char *err) {
  if (src.path != nullptr) return ts_check_file(src.path, head, err);
  head.n = std::min(src.len, sizeof(head.b));
  if (head.n > 0) memcpy(head.b, src.data, head.n);
  return 0;
}

/* The OpenImageIO reader for a file starting with these bytes, or nullptr
 * for anything but the four supported formats. */
static const char *ts_sniff(const ts_head &h) {
  static const struct {
    const char *format;
    uint8_t len;
    uint8_t magic[8];
  } kMagic[] = {
      {"png", 8, {0x89, 'P', 'N', 'G', 0x0d, 0x0a, 0x1a, 0x0a}},
      {"jpeg", 3, {0xff, 0xd8, 0xff}},
      {"tiff", 4, {'I', 'I', 42, 0}}, /* classic, little- and big-endian */
      {"tiff", 4, {'M', 'M', 0, 42}},
      {"tiff", 4, {'I', 'I', 43, 0}}, /* BigTIFF */
      {"tiff", 4, {'M', 'M', 0, 43}},
      {"openexr", 4, {0x76, 0x2f, 0x31, 0x01}},
  };
  for (const auto &m : kMagic)
    if (h.n >= m.len && memcmp(h.b, m.magic, m.len) == 0) return m.format;
  return nullptr;
}

static int ts_check_spec(const char *name, const ImageSpec &s, const ts_image_limits *limits,
                         char *err) {
  uint64_t max_pixels = limits != nullptr && limits->max_pixels != 0 ? limits->max_pixels
                                                                     : TS_IMAGE_DEFAULT_MAX_PIXELS;
  const char *option =
      limits != nullptr && limits->option != nullptr ? limits->option : "--max-pixels";
  if (s.width <= 0 || s.height <= 0 || s.nchannels <= 0)
    return ts_error(err, TS_EFORMAT, "%s: invalid image size %dx%d with %d channels", name, s.width,
                    s.height, s.nchannels);
  if (s.depth > 1)
    return ts_error(err, TS_EFORMAT, "%s: volume images (depth %d) are not supported", name,
                    s.depth);
  if (s.deep) return ts_error(err, TS_EFORMAT, "%s: deep images are not supported", name);
  if (s.nchannels > TS_IMAGE_MAX_CHANNELS)
    return ts_error(err, TS_EFORMAT, "%s: %d channels; at most %d are supported", name, s.nchannels,
                    TS_IMAGE_MAX_CHANNELS);
  if (!s.channelformats.empty() && s.channelformats.size() != (size_t)s.nchannels)
    return ts_error(err, TS_EFORMAT, "%s: %zu channel formats for %d channels", name,
                    s.channelformats.size(), s.nchannels);
  uint64_t pixels = (uint64_t)s.width * (uint64_t)s.height;
  if (pixels > max_pixels)
    return ts_error(err, TS_ETOOBIG,
                    "%s: %dx%d image (%llu pixels) is over the limit of %llu "
                    "pixels; raise it with %s",
                    name, s.width, s.height, (unsigned long long)pixels,
                    (unsigned long long)max_pixels, option);
  /* A tiled reader holds whole tiles: a tiny image must not claim huge
   * ones. */
  uint64_t tile = (uint64_t)std::max(s.tile_width, 0) * (uint64_t)std::max(s.tile_height, 0);
  if (s.tile_width < 0 || s.tile_height < 0 || tile > max_pixels)
    return ts_error(err, TS_ETOOBIG,
                    "%s: %dx%d tiles are over the limit of %llu pixels; raise it with %s",
                    name, s.tile_width, s.tile_height, (unsigned long long)max_pixels, option);
  return 0;
}

/* The source as a FILE: the file itself, or fmemopen over the bytes
 * (fmemopen only reads here; the cast is what its prototype wants). */
static FILE *ts_source_file(const ts_source &src) {
  return src.path != nullptr ? fopen(src.path, "rb")
                             : fmemopen((void *)src.data, src.len, "rb");
}

/* File bytes fit for a one-line message: printable ASCII as is, the rest
 * as \xNN, at most 40 bytes shown. */
static std::string ts_printable(const std::string &raw) {
  std::string out;
  for (size_t i = 0; i < raw.size() && i < 40; i++) {
    unsigned char c = (unsigned char)raw[i];
    if (c >= 0x20 && c < 0x7f && c != '\\') {
      out += (char)c;
    } else {
      char hex[8];
      snprintf(hex, sizeof(hex), "\\x%02x", c);
      out += hex;
    }
  }
  if (raw.size() > 40) out += "...";
  return out;
}

/* libpng allocates (and this build touches) a text chunk at the length
 * the file claims: 322 bytes claiming a 1.8 GB tEXt took 1.9 GB of memory
 * (found by fuzz_image). Every chunk length is checked against the bytes
 * left first, up to IEND; a file cut short fails here as truncated. */
static bool ts_png_sizes_ok(FILE *f, std::string &why) {
  if (fseeko(f, 0, SEEK_END) != 0) return false;
  off_t end = ftello(f);
  if (end < 8 || fseeko(f, 8, SEEK_SET) != 0) return false;
  for (off_t pos = 8; pos < end;) {
    uint8_t h[8];
    if (end - pos < 12 || fread(h, 1, 8, f) != 8) {
      why = "file ends inside a chunk header";
      return false;
    }
    uint32_t len = (uint32_t)h[0] << 24 | h[1] << 16 | h[2] << 8 | h[3];
    std::string type((const char *)h + 4, 4);
    if (len > 0x7fffffffu || (off_t)len > end - pos - 12) {
      why = "chunk '" + ts_printable(type) + "' claims " + std::to_string(len) +
            " bytes, the file has " + std::to_string((long long)(end - pos - 12)) + " left";
      return false;
    }
    if (type == "IEND") return true;
    pos += 12 + (off_t)len;
    if (fseeko(f, pos, SEEK_SET) != 0) return false;
  }
  why = "no IEND chunk";
  return false;
}

/* OpenEXR 3.1 allocates every header attribute at the size the file
 * claims before reading it (found by fuzz_image: a 707-byte file asking
 * for 1.2 GB), so the attribute sizes are checked against the bytes the
 * file has first. Walks the header (every header of a multi-part file):
 * name, type name, int32 size, value; an empty name ends a header. Only
 * the sizes are judged; OpenEXR parses the rest. */
static bool ts_exr_sizes_ok(FILE *f, std::string &why) {
  if (fseeko(f, 0, SEEK_END) != 0) return false;
  off_t end = ftello(f);
  uint8_t v[4];
  if (end < 8 || fseeko(f, 4, SEEK_SET) != 0 || fread(v, 1, 4, f) != 4) {
    why = "header cut short";
    return false;
  }
  bool multipart = (v[1] & 0x10) != 0; /* version flag bit 12 */
  for (int headers = 0;; headers++) {
    for (int attrs = 0;; attrs++) {
      std::string text[2];
      for (int t = 0; t < 2; t++) {
        int c;
        while ((c = fgetc(f)) > 0 && text[t].size() < 256) text[t] += (char)c;
        if (c < 0 || text[t].size() >= 256) {
          why = c < 0 ? "header cut short" : "header attribute name over 255 bytes";
          return false;
        }
        if (t == 0 && text[0].empty()) break; /* end of this header */
      }
      if (text[0].empty()) {
        if (attrs == 0 && headers > 0) return true; /* the empty header ends the list */
        break;
      }
      uint8_t b[4];
      if (fread(b, 1, 4, f) != 4) {
        why = "header cut short";
        return false;
      }
      int64_t size = (int32_t)(b[0] | b[1] << 8 | b[2] << 16 | (uint32_t)b[3] << 24);
      off_t here = ftello(f);
      if (size < 0 || here < 0 || size > end - here) {
        why = "header attribute '" + ts_printable(text[0]) + "' claims " + std::to_string(size) +
              " bytes, more than the file holds";
        return false;
      }
      if (fseeko(f, (off_t)size, SEEK_CUR) != 0) return false;
    }
    if (!multipart) return true;
  }
}

/* OpenImageIO's reader of bytes in memory, bounds-checked. IOMemReader
 * 2.4 checks `offset + size` in unsigned arithmetic only, so a negative
 * offset (OpenEXR follows a line offset table a file can fill with -1)
 * reads before the buffer. Here every read starts inside the bytes. */
class ts_memreader final : public OIIO::Filesystem::IOMemReader {
 public:
  ts_memreader(const void *buf, size_t size) : IOMemReader(buf, size) {}
  bool seek(int64_t offset) override { return offset >= 0 && IOMemReader::seek(offset); }
  size_t pread(void *buf, size_t size, int64_t offset) override {
    if (offset < 0 || (uint64_t)offset >= (uint64_t)m_buf.size()) return 0;
    return IOMemReader::pread(buf, size, offset);
  }
  size_t read(void *buf, size_t size) override {
    size_t n = pread(buf, size, tell());
    IOMemReader::seek(tell() + (int64_t)n);
    return n;
  }
};

/* An open reader and, for bytes in memory, the proxy it reads through
 * (declared first: it must outlive the reader). */
struct ts_input {
  std::unique_ptr<ts_memreader> mem;
  std::unique_ptr<ImageInput> in;
};

/* The sizes an OpenEXR header or PNG chunk list claims, checked against
 * the bytes there are before OpenImageIO opens the file. */
static int ts_check_sizes(const ts_source &src, const char *format, char *err) {
  bool exr = strcmp(format, "openexr") == 0;
  if (!exr && strcmp(format, "png") != 0) return 0;
  std::string why = exr ? "cannot read the header" : "cannot read the chunks";
  ts_file f(ts_source_file(src));
  if (f && (exr ? ts_exr_sizes_ok(f.get(), why) : ts_png_sizes_ok(f.get(), why))) return 0;
  return ts_error(err, TS_EFORMAT, exr ? "%s: not a readable openexr image: %s" : "%s: unreadable or truncated image: %s",
                  src.name, why.c_str());
}

/* Everything up to the pixels: the format from the first bytes, the
 * header, the checks. Shared by every read and probe. */
static int ts_open(const ts_source &src, const ts_image_limits *limits, ts_input &io, char *err) {
  ts_head head;
  int rc = ts_source_head(src, head, err);
  if (rc != 0) return rc;
  if (head.n == 0) return ts_error(err, TS_EFORMAT, "%s: empty file (0 bytes), not an image", src.name);
  const char *format = ts_sniff(head);
  if (format == nullptr) {
    char hex[3 * sizeof(head.b) + 1] = "";
    for (size_t i = 0, k = 0; i < head.n; i++, k = strlen(hex))
      snprintf(hex + k, sizeof(hex) - k, "%s%02x", i ? " " : "", head.b[i]);
    return ts_error(err, TS_EFORMAT,
                    "%s: not a PNG, JPEG, TIFF or OpenEXR image (starts with bytes %s)", src.name,
                    hex);
  }
  rc = ts_check_sizes(src, format, err);
  if (rc != 0) return rc;
  ImageSpec config;
  config.attribute("oiio:UnassociatedAlpha", 1); /* pixel values as stored */
  if (src.path == nullptr) {
    io.mem.reset(new ts_memreader(src.data, src.len));
    void *proxy = io.mem.get(); /* how OpenImageIO 2.4's open() takes it */
    config.attribute("oiio:ioproxy", TypeDesc::PTR, &proxy);
  }
  io.in = ImageInput::create(format, false, &config, io.mem.get());
  if (!io.in)
    return ts_error(err, TS_EFORMAT, "%s: no %s reader in this OpenImageIO: %s", src.name, format,
                    ts_oneline(OIIO::geterror()).c_str());
  ImageSpec spec;
  if (!io.in->open(src.path != nullptr ? src.path : src.name, spec, config))
    return ts_error(err, TS_EFORMAT, "%s: not a readable %s image: %s", src.name, format,
                    ts_oneline(io.in->geterror()).c_str());
  io.in->geterror(); /* notes from parsing the header do not fail the read */
  return ts_check_spec(src.name, io.in->spec(), limits, err);
}

static int ts_read(const ts_source &src, ts_image *out, const ts_image_limits *limits, char *err) {
  ts_input io;
  int rc = ts_open(src, limits, io, err);
  if (rc != 0) return rc;
  const ImageSpec &spec = io.in->spec();
  ts_image_holder h;
  char why[TS_ERR_LEN];
  ts_pixtype type = ts_spec_type(spec);
  rc = ts_image_alloc(&h.img, spec.width, spec.height, spec.nchannels, type, why);
  if (rc != 0) return ts_error(err, rc, "%s: %s", src.name, why);
  bool ok = io.in->read_image(0, 0, 0, spec.nchannels, ts_oiio_type(type), h.img.pixels);
  std::string reason = io.in->geterror();
  if (!ok || !reason.empty())
    return ts_error(err, TS_EFORMAT, "%s: unreadable or truncated image: %s", src.name,
                    ts_oneline(reason).c_str());

  std::unique_ptr<ts_meta> meta(new ts_meta);
  meta->attribs = spec.extra_attribs;
  if (OIIO::Strutil::iequals(io.in->format_name(), "tiff")) {
    FILE *f = ts_source_file(src);
    if (f != nullptr) ts_geo_read(ts_file(f), meta->attribs);
  }
  h.img.meta = meta.release();
  *out = h.img;
  h.img = ts_image{};
  return 0;
}

static int ts_probe(const ts_source &src, const ts_image_limits *limits, ts_image_info *info,
                    char *err) {
  ts_input io;
  int rc = ts_open(src, limits, io, err);
  if (rc == 0 && info != nullptr) {
    const ImageSpec &spec = io.in->spec();
    *info = ts_image_info{spec.width, spec.height, spec.nchannels, ts_spec_type(spec)};
  }
  return rc;
}

/* --- write --------------------------------------------------------------- */

/* The sample type a format is given: what it stores natively, or the
 * nearest it holds. Formats not named here get the image's type and
 * OpenImageIO converts to what they hold. */
static TypeDesc ts_out_type(const std::string &fmt, ts_pixtype t) {
  if (fmt == "png") return t == TS_PIX_U16 ? TypeDesc::UINT16 : TypeDesc::UINT8;
  if (fmt == "jpeg") return TypeDesc::UINT8;
  if (fmt == "tiff" && t == TS_PIX_F16) return TypeDesc::FLOAT;    /* half TIFF is rare */
  if (fmt == "openexr" && t == TS_PIX_U8) return TypeDesc::HALF;   /* exact for 8 bits */
  if (fmt == "openexr" && t == TS_PIX_U16) return TypeDesc::FLOAT; /* exact for 16 */
  return ts_oiio_type(t);
}

/* JPEG holds grey or RGB: alpha and extra channels are left out. */
static int ts_out_channels(const std::string &fmt, int channels) {
  if (fmt == "jpeg") return channels >= 3 ? 3 : 1;
  return channels;
}

static void ts_out_channel_names(ImageSpec &spec) {
  if (spec.nchannels == 1) {
    spec.channelnames = {"Y"};
    spec.alpha_channel = -1;
  } else if (spec.nchannels == 2) {
    spec.channelnames = {"Y", "A"};
    spec.alpha_channel = 1;
  }
}

/* Lossless defaults, JPEG at quality 95. Pixel values are written as they
 * are: OpenImageIO must not premultiply or unpremultiply alpha. */
static void ts_out_defaults(const std::string &fmt, ImageSpec &spec) {
  spec.attribute("oiio:UnassociatedAlpha", 1);
  if (fmt == "jpeg") spec.attribute("compression", "jpeg:95");
  if (fmt == "tiff" || fmt == "openexr") spec.attribute("compression", "zip");
}

/* Removes the temporary file unless the write was committed. */
struct ts_tmpfile {
  std::string path;
  bool keep = false;
  ~ts_tmpfile() {
    if (!keep) unlink(path.c_str());
  }
};

static std::atomic<unsigned> ts_tmp_seq{0};

static int ts_check_image(const char *path, const ts_image *img, char *err) {
  if (img == nullptr || img->pixels == nullptr)
    return ts_error(err, TS_EINVAL, "%s: no image to write", path);
  if (img->width <= 0 || img->height <= 0 || img->channels < 1 ||
      img->channels > TS_IMAGE_MAX_CHANNELS || ts_pixtype_size(img->type) == 0)
    return ts_error(err, TS_EINVAL, "%s: invalid image %dx%d, %d channels, type %d", path,
                    img->width, img->height, img->channels, (int)img->type);
  return 0;
}

static int ts_sync(const char *path, std::string &why) {
  int fd = open(path, O_RDONLY);
  if (fd < 0 || fsync(fd) != 0) {
    why = strerror(errno);
    if (fd >= 0) close(fd);
    return -1;
  }
  close(fd);
  return 0;
}

static int ts_write(const char *path, const ts_image *img, const ts_meta *meta_from, char *err) {
  int rc = ts_check_image(path, img, err);
  if (rc != 0) return rc;
  /* The temporary name keeps the directory (rename must not cross file
   * systems); the format is chosen from path's own extension. Declared
   * before the writer, so the writer is closed before the file goes. */
  ts_tmpfile tmp;
  tmp.path =
      std::string(path) + ".tmp-" + std::to_string(getpid()) + "-" + std::to_string(ts_tmp_seq++);
  auto out = ImageOutput::create(path);
  if (!out)
    return ts_error(err, TS_EINVAL,
                    "%s: no image format for this file name; use .png, .jpg, "
                    ".tif or .exr",
                    path);
  std::string fmt = out->format_name();
  ImageSpec spec(img->width, img->height, ts_out_channels(fmt, img->channels),
                 ts_out_type(fmt, img->type));
  ts_out_channel_names(spec);
  if (meta_from != nullptr)
    for (const ParamValue &p : meta_from->attribs)
      if (ts_meta_passes(p.name().string())) spec.extra_attribs.add_or_replace(p);
  ts_out_defaults(fmt, spec);

  size_t tsize = ts_pixtype_size(img->type);
  OIIO::stride_t xstride = (OIIO::stride_t)(img->channels * tsize);
  std::string why;
  bool ok = out->open(tmp.path, spec);
  if (ok) {
    ok = out->write_image(ts_oiio_type(img->type), img->pixels, xstride, xstride * img->width);
    ok = out->close() && ok; /* close even after a failed write */
  }
  if (!ok) why = ts_oneline(out->geterror());
  if (ok && fmt == "tiff" && meta_from != nullptr && ts_has_geo(meta_from->attribs))
    ok = ts_geo_write(tmp.path.c_str(), meta_from->attribs, why);
  /* fsync before rename: after a crash the name holds the old file or the
   * whole new one, never an empty one. */
  ok = ok && ts_sync(tmp.path.c_str(), why) == 0;
  if (ok && rename(tmp.path.c_str(), path) != 0) {
    why = strerror(errno);
    ok = false;
  }
  if (!ok) return ts_error(err, TS_EIO, "%s: cannot write image: %s", path, why.c_str());
  tmp.keep = true;
  return 0;
}

/* --- C API --------------------------------------------------------------- */

/* Runs a read or probe behind the C boundary: every exception becomes a
 * code and a message naming the file. */
template <typename F>
static int ts_guard(const char *name, char *err, F body) {
  try {
    ts_oiio_errscope scope;
    return body();
  } catch (const std::bad_alloc &) {
    return ts_error(err, TS_ENOMEM, "%s: out of memory reading the image", name);
  } catch (const std::exception &e) {
    return ts_error(err, TS_EFORMAT, "%s: unreadable image: %s", name,
                    ts_oneline(e.what()).c_str());
  } catch (...) {
    return ts_error(err, TS_EFORMAT, "%s: unreadable image", name);
  }
}

extern "C" int ts_image_read(const char *path, ts_image *img, const ts_image_limits *limits,
                             char *err) {
  if (img == nullptr) return ts_error(err, TS_EINVAL, "no image to read into");
  *img = ts_image{};
  if (path == nullptr || *path == '\0') return ts_error(err, TS_EINVAL, "no image file name given");
  ts_source src{path, path, nullptr, 0};
  return ts_guard(path, err, [&] { return ts_read(src, img, limits, err); });
}

extern "C" int ts_image_read_mem(const char *name, const void *data, size_t len, ts_image *img,
                                 const ts_image_limits *limits, char *err) {
  if (img == nullptr) return ts_error(err, TS_EINVAL, "no image to read into");
  *img = ts_image{};
  if (name == nullptr || *name == '\0') name = "(image in memory)";
  if (data == nullptr && len != 0) return ts_error(err, TS_EINVAL, "%s: no bytes given", name);
  ts_source src{name, nullptr, (const uint8_t *)data, len};
  return ts_guard(name, err, [&] { return ts_read(src, img, limits, err); });
}

extern "C" int ts_image_probe_mem(const char *name, const void *data, size_t len,
                                  const ts_image_limits *limits, ts_image_info *info, char *err) {
  if (name == nullptr || *name == '\0') name = "(image in memory)";
  if (data == nullptr && len != 0) return ts_error(err, TS_EINVAL, "%s: no bytes given", name);
  ts_source src{name, nullptr, (const uint8_t *)data, len};
  return ts_guard(name, err, [&] { return ts_probe(src, limits, info, err); });
}

extern "C" int ts_image_write(const char *path, const ts_image *img, const ts_meta *meta_from,
                              char *err) {
  if (path == nullptr || *path == '\0')
    return ts_error(err, TS_EINVAL, "no output file name given");
  try {
    ts_oiio_errscope scope;
    return ts_write(path, img, meta_from, err);
  } catch (const std::bad_alloc &) {
    return ts_error(err, TS_ENOMEM, "%s: out of memory writing the image", path);
  } catch (const std::exception &e) {
    return ts_error(err, TS_EIO, "%s: cannot write image: %s", path, ts_oneline(e.what()).c_str());
  } catch (...) {
    return ts_error(err, TS_EIO, "%s: cannot write image", path);
  }
}

extern "C" int ts_meta_get(const ts_meta *meta, const char *name, char *out, size_t outlen) {
  if (meta == nullptr || name == nullptr) return TS_ENOENT;
  try {
    auto p = meta->attribs.find(name, TypeDesc::UNKNOWN, false);
    if (p == meta->attribs.end()) return TS_ENOENT;
    if (out != nullptr && outlen > 0) {
      /* At most as many elements as could fit, each taking >= 1 char. */
      int maxn = (int)std::min<size_t>(outlen, 1u << 20);
      snprintf(out, outlen, "%s", p->get_string(maxn).c_str());
    }
    return 0;
  } catch (...) {
    return TS_ENOENT;
  }
}

extern "C" int ts_meta_set(ts_meta **meta, const char *name, const char *value) {
  if (meta == nullptr || name == nullptr || *name == '\0' || value == nullptr) return TS_EINVAL;
  try {
    std::unique_ptr<ts_meta> fresh;
    if (*meta == nullptr) fresh.reset(new ts_meta);
    ts_meta *m = *meta != nullptr ? *meta : fresh.get();
    m->attribs.add_or_replace(ParamValue(name, OIIO::string_view(value)), false);
    if (fresh) *meta = fresh.release();
    return 0;
  } catch (...) {
    return TS_ENOMEM;
  }
}

extern "C" void ts_meta_free(ts_meta *meta) { delete meta; }
