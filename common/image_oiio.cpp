/* image_oiio.cpp - image files through OpenImageIO; see image.h.
 *
 * The only C++ in texsyn: a thin shim that keeps OpenImageIO's types and
 * exceptions on this side of an extern "C" boundary. Every entry point
 * catches everything and answers with a TS_E* code and one line in err.
 * It is built into libtexsyn-image.so, whose one exported symbol is the
 * table of these entry points at the end of this file (image_lib.h).
 *
 * Reads take a file or a file's bytes in memory (through OpenImageIO's
 * IOMemReader, bounds-checked); both go through ts_open and ts_read, so a reference the
 * coordinator probes at submit and reads later is checked the same way.
 * Before any decoder sees the bytes, image_check.c picks the reader from
 * the first bytes (PNG, JPEG, TIFF and OpenEXR only) and checks the sizes
 * a PNG or OpenEXR header claims; the header OpenImageIO parsed is then
 * checked here (ts_check_spec) before any pixel memory is taken.
 *
 * Three things OpenImageIO 2.4 does not do for us, handled here:
 *  - A failed read is not always a false return: libtiff strip errors and
 *    libjpeg's "premature end of file" leave read_image() true with a
 *    pending error. Any pending error after a read fails it, so a truncated
 *    file never yields a partially grey image.
 *  - Its per-thread global error message outlives the call that set it; we
 *    clear it on entry and exit so one call's failure never shows in the
 *    next call's message.
 *  - It neither reads nor writes GeoTIFF tags. tiff_tags.c reads the raw
 *    tags of the first TIFF directory and, when writing a TIFF, appends
 *    them to the file OpenImageIO wrote; here they become metadata and
 *    back (see "GeoTIFF" below). */
#include <errno.h>
#include <fcntl.h>
#include <stdio.h>
#include <string.h>
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
#include "image_check.h"
#include "image_lib.h"
#include "image_meta.h"
#include "tiff_tags.h"

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
 * tiff_tags.c reads and writes the raw tags; here they become typed
 * attributes (string, uint16[], double[]) and back. */

static bool ts_is_geo_attr(const std::string &name) {
  return ts_geotag_named(name.c_str()) != nullptr;
}

struct ts_file_closer {
  void operator()(FILE *f) const { fclose(f); }
};
typedef std::unique_ptr<FILE, ts_file_closer> ts_file;

/* Tag values read by ts_geo_read, freed on every way out. */
struct ts_geo_read_set {
  ts_geo_value v[TS_GEOTAG_COUNT] = {};
  ~ts_geo_read_set() { ts_geo_free(v); }
};

/* Adds the GeoTIFF tags of the first directory of the TIFF in f (a file,
 * or fmemopen'ed bytes) to attrs. A malformed tag is skipped, not an
 * error: the pixels are still good. */
static void ts_geo_read_attrs(FILE *f, ParamValueList &attrs) {
  ts_geo_read_set tags;
  if (ts_geo_read(f, tags.v) != 0) throw std::bad_alloc();
  for (int i = 0; i < TS_GEOTAG_COUNT; i++) {
    const ts_geotag &g = ts_geotags[i];
    const ts_geo_value &v = tags.v[i];
    if (v.values == nullptr) continue;
    if (g.type == TS_TIFF_ASCII) {
      std::string s((const char *)v.values, v.count);
      while (!s.empty() && s.back() == '\0') s.pop_back();
      attrs.add_or_replace(ParamValue(g.name, OIIO::string_view(s)));
    } else {
      TypeDesc::BASETYPE base = g.type == TS_TIFF_SHORT ? TypeDesc::UINT16 : TypeDesc::DOUBLE;
      attrs.add_or_replace(ParamValue(g.name, TypeDesc(base, (int)v.count), 1, v.values));
    }
  }
}

/* The GeoTIFF attributes of attrs as tag values, pointing into attrs (and
 * into strings for the text ones, NUL-terminated as TIFF wants).
 * Attributes of the wrong type (not from a GeoTIFF) are left out. */
static void ts_geo_collect(const ParamValueList &attrs, ts_geo_value tags[TS_GEOTAG_COUNT],
                           std::string strings[TS_GEOTAG_COUNT]) {
  for (int i = 0; i < TS_GEOTAG_COUNT; i++) {
    const ts_geotag &g = ts_geotags[i];
    tags[i] = ts_geo_value{0, nullptr};
    auto p = attrs.find(g.name, TypeDesc::UNKNOWN, false);
    if (p == attrs.end()) continue;
    TypeDesc ty = p->type();
    size_t n = ty.basevalues() * (size_t)p->nvalues();
    if (g.type == TS_TIFF_ASCII && ty == OIIO::TypeString && n == 1) {
      strings[i] = p->get_string();
      tags[i] = ts_geo_value{strings[i].size() + 1, strings[i].c_str()};
    } else if ((g.type == TS_TIFF_SHORT && ty.basetype == TypeDesc::UINT16) ||
               (g.type == TS_TIFF_DOUBLE && ty.basetype == TypeDesc::DOUBLE)) {
      tags[i] = ts_geo_value{n, p->data()};
    }
  }
}

static bool ts_has_geo(const ParamValueList &attrs) {
  for (const ParamValue &p : attrs)
    if (ts_is_geo_attr(p.name().string())) return true;
  return false;
}

/* Writes attrs' GeoTIFF tags into the TIFF at path (see tiff_tags.h). */
static bool ts_geo_write_attrs(const char *path, const ParamValueList &attrs, std::string &why) {
  ts_geo_value tags[TS_GEOTAG_COUNT];
  std::string strings[TS_GEOTAG_COUNT];
  ts_geo_collect(attrs, tags, strings);
  char reason[TS_ERR_LEN];
  int rc = ts_geo_write(path, tags, reason);
  if (rc == TS_ENOMEM) throw std::bad_alloc();
  if (rc != 0) why = reason;
  return rc == 0;
}

/* --- metadata ------------------------------------------------------------ */

/* Whether a source attribute is passed on to an output. Dropped: whatever
 * describes how the source was encoded rather than what the image is
 * (compression, strip and tile layout, bit depth, JPEG subsampling,
 * OpenImageIO's reader notes, EXIF pixel dimensions, thumbnails), which
 * the target format and our own defaults decide; and the GeoTIFF tags,
 * which only TIFF outputs get, written by ts_geo_write_attrs. Kept: everything
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

/* Everything up to the pixels: the format from the first bytes, the
 * header, the checks. Shared by every read and probe. */
static int ts_open(const ts_image_src &src, const ts_image_limits *limits, ts_input &io, char *err) {
  const char *format;
  int rc = ts_image_sniff(&src, &format, err);
  if (rc == 0) rc = ts_image_check_sizes(&src, format, err);
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

static int ts_read(const ts_image_src &src, ts_image *out, const ts_image_limits *limits, char *err) {
  ts_input io;
  int rc = ts_open(src, limits, io, err);
  if (rc != 0) return rc;
  const ImageSpec &spec = io.in->spec();
  ts_image_holder h;
  char why[TS_ERR_LEN];
  ts_pixtype type = ts_spec_type(spec);
  rc = ts_image_alloc(&h.img, spec.width, spec.height, spec.nchannels, type, why);
  if (rc != 0) return ts_error(err, rc, "%s: %s", src.name, why);
  /* The file's own type is asked for as UNKNOWN (native): OpenImageIO 2.4
   * then reads straight into the buffer, while naming it, even unchanged,
   * sends every read through a 64 MB scratch buffer. Same bytes either way. */
  TypeDesc want = ts_oiio_type(type);
  if (spec.channelformats.empty() && want == spec.format) want = TypeDesc::UNKNOWN;
  bool ok = io.in->read_image(0, 0, 0, spec.nchannels, want, h.img.pixels);
  std::string reason = io.in->geterror();
  if (!ok || !reason.empty())
    return ts_error(err, TS_EFORMAT, "%s: unreadable or truncated image: %s", src.name,
                    ts_oneline(reason).c_str());

  std::unique_ptr<ts_meta> meta(new ts_meta);
  meta->attribs = spec.extra_attribs;
  if (OIIO::Strutil::iequals(io.in->format_name(), "tiff")) {
    ts_file f(ts_image_src_open(&src));
    if (f) ts_geo_read_attrs(f.get(), meta->attribs);
  }
  h.img.meta = meta.release();
  *out = h.img;
  h.img = ts_image{};
  return 0;
}

static int ts_probe(const ts_image_src &src, const ts_image_limits *limits, ts_image_info *info,
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

/* Lossless defaults (PNG at zlib level 1), JPEG at quality 95. Alpha keeps its meaning: samples
 * of a source with associated (premultiplied) alpha, e.g. a TIFF with
 * ExtraSamples=1, are written as associated - TIFF and EXR keep samples
 * and label, a format that stores straight alpha only (PNG) gets them
 * unpremultiplied by OpenImageIO. Straight alpha, and images of no source
 * (copy maps), are written as they are. */
static void ts_out_defaults(const std::string &fmt, ImageSpec &spec, const ts_meta *meta_from) {
  bool assoc = meta_from != nullptr && spec.alpha_channel >= 0 &&
               meta_from->attribs.get_int("oiio:UnassociatedAlpha", 0) == 0;
  spec.attribute("oiio:UnassociatedAlpha", assoc ? 0 : 1);
  if (fmt == "jpeg") spec.attribute("compression", "jpeg:95");
  if (fmt == "tiff" || fmt == "openexr") spec.attribute("compression", "zip");
  /* zlib's fastest level, OpenCV's default too: an 8192^2 result encodes
   * ~3x faster than at OpenImageIO's level 6, for a file ~20% larger. The
   * coordinator writes every result on its own, while the workers wait for
   * the next job, so the encoding is serial time in every scaling figure. */
  if (fmt == "png") spec.attribute("png:compressionLevel", 1);
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

/* The encoded bytes into a new file, every error checked. The PNG and JPEG
 * encoders write into memory (ts_write), so a full disk or a failing
 * device is met here, not by a codec that overlooks it (the PNG writer
 * left an empty file and reported success) or exits the process on it
 * (libjpeg's default error handler). The TIFF and OpenEXR writers report
 * write errors and write their files themselves: OpenImageIO 2.4's TIFF
 * writer makes a broken file through a memory sink. */
static int ts_write_file(const std::string &path, const std::vector<unsigned char> &bytes, std::string &why) {
  int fd = open(path.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) {
    why = strerror(errno);
    return -1;
  }
  size_t off = 0;
  while (off < bytes.size()) {
    ssize_t k = write(fd, bytes.data() + off, bytes.size() - off);
    if (k < 0 && errno == EINTR) continue;
    if (k <= 0) {
      why = k < 0 ? strerror(errno) : "the device took no more bytes";
      close(fd);
      return -1;
    }
    off += (size_t)k;
  }
  if (close(fd) != 0) {
    why = strerror(errno);
    return -1;
  }
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
  ts_out_defaults(fmt, spec, meta_from);

  size_t tsize = ts_pixtype_size(img->type);
  OIIO::stride_t xstride = (OIIO::stride_t)(img->channels * tsize);
  std::string why;
  std::vector<unsigned char> bytes;
  OIIO::Filesystem::IOVecOutput sink(bytes);
  bool in_memory = fmt == "png" || fmt == "jpeg";
  bool ok = (!in_memory || out->set_ioproxy(&sink)) && out->open(tmp.path, spec);
  if (ok) {
    ok = out->write_image(ts_oiio_type(img->type), img->pixels, xstride, xstride * img->width);
    ok = out->close() && ok; /* close even after a failed write */
  }
  if (!ok) why = ts_oneline(out->geterror());
  if (ok && in_memory && ts_write_file(tmp.path, bytes, why) != 0) ok = false;
  if (ok && fmt == "tiff" && meta_from != nullptr && ts_has_geo(meta_from->attribs))
    ok = ts_geo_write_attrs(tmp.path.c_str(), meta_from->attribs, why);
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
  ts_image_src src{path, path, nullptr, 0};
  return ts_guard(path, err, [&] { return ts_read(src, img, limits, err); });
}

extern "C" int ts_image_read_mem(const char *name, const void *data, size_t len, ts_image *img,
                                 const ts_image_limits *limits, char *err) {
  if (img == nullptr) return ts_error(err, TS_EINVAL, "no image to read into");
  *img = ts_image{};
  if (name == nullptr || *name == '\0') name = "(image in memory)";
  if (data == nullptr && len != 0) return ts_error(err, TS_EINVAL, "%s: no bytes given", name);
  ts_image_src src{name, nullptr, (const uint8_t *)data, len};
  return ts_guard(name, err, [&] { return ts_read(src, img, limits, err); });
}

extern "C" int ts_image_probe_mem(const char *name, const void *data, size_t len,
                                  const ts_image_limits *limits, ts_image_info *info, char *err) {
  if (name == nullptr || *name == '\0') name = "(image in memory)";
  if (data == nullptr && len != 0) return ts_error(err, TS_EINVAL, "%s: no bytes given", name);
  ts_image_src src{name, nullptr, (const uint8_t *)data, len};
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

extern "C" int ts_meta_copy(const ts_meta *from, ts_meta **to) {
  if (to == nullptr) return TS_EINVAL;
  try {
    std::unique_ptr<ts_meta> copy(new ts_meta);
    if (from != nullptr) copy->attribs = from->attribs;
    delete *to;
    *to = copy.release();
    return 0;
  } catch (...) {
    return TS_ENOMEM;
  }
}

/* --- movies ------------------------------------------------------------- *
 *
 * OpenImageIO's FFmpeg reader, asked for by name: the sniffing of ts_open
 * (four formats) is for files that may come from the network; a movie is
 * only ever a file named on texsyn video's command line. */

static int ts_movie_open(const char *path, const ts_image_limits *limits, std::unique_ptr<ImageInput> &in,
                         int &frames, char *err) {
  if (access(path, R_OK) != 0)
    return ts_error(err, errno == ENOENT ? TS_ENOENT : TS_EFORMAT, "%s: %s", path, strerror(errno));
  in = ImageInput::create("ffmpeg");
  if (!in)
    return ts_error(err, TS_EFORMAT, "%s: this OpenImageIO has no FFmpeg reader for movies: %s", path,
                    ts_oneline(OIIO::geterror()).c_str());
  ImageSpec spec;
  if (!in->open(path, spec))
    return ts_error(err, TS_EFORMAT, "%s: not a movie FFmpeg reads: %s", path, ts_oneline(in->geterror()).c_str());
  in->geterror();
  frames = in->spec().get_int_attribute("oiio:subimages", 0);
  if (frames <= 0) return ts_error(err, TS_EFORMAT, "%s: a movie without frames", path);
  return ts_check_spec(path, in->spec(), limits, err);
}

static int ts_movie_probe_(const char *path, const ts_image_limits *limits, ts_movie_info *info, char *err) {
  std::unique_ptr<ImageInput> in;
  int frames = 0;
  int rc = ts_movie_open(path, limits, in, frames, err);
  if (rc == 0 && info != nullptr) {
    const ImageSpec &spec = in->spec();
    info->frames = frames;
    info->fps = spec.get_float_attribute("FramesPerSecond", 0.0f);
    info->frame = ts_image_info{spec.width, spec.height, spec.nchannels, ts_spec_type(spec)};
  }
  return rc;
}

static int ts_movie_read_(const char *path, long first, long last, const ts_image_limits *limits,
                          ts_movie_frame_fn each, void *ctx, char *err) {
  std::unique_ptr<ImageInput> in;
  int frames = 0;
  int rc = ts_movie_open(path, limits, in, frames, err);
  if (rc == 0 && (first < 0 || last >= frames || first > last))
    return ts_error(err, TS_EINVAL, "%s: frames %ld..%ld asked for, the movie has 0..%d", path, first, last,
                    frames - 1);
  for (long f = first; rc == 0 && f <= last; f++) {
    if (!in->seek_subimage((int)f, 0))
      return ts_error(err, TS_EFORMAT, "%s: cannot reach frame %ld: %s", path, f, ts_oneline(in->geterror()).c_str());
    const ImageSpec &spec = in->spec();
    rc = ts_check_spec(path, spec, limits, err);
    ts_image_holder h;
    char why[TS_ERR_LEN];
    ts_pixtype type = ts_spec_type(spec);
    if (rc == 0 && (rc = ts_image_alloc(&h.img, spec.width, spec.height, spec.nchannels, type, why)) != 0)
      return ts_error(err, rc, "%s frame %ld: %s", path, f, why);
    if (rc == 0) {
      bool ok = in->read_image((int)f, 0, 0, spec.nchannels, ts_oiio_type(type), h.img.pixels);
      std::string reason = in->geterror();
      if (!ok || !reason.empty())
        return ts_error(err, TS_EFORMAT, "%s: frame %ld unreadable: %s", path, f, ts_oneline(reason).c_str());
      rc = each(ctx, f, &h.img, err);
    }
  }
  return rc;
}

extern "C" int ts_movie_probe(const char *path, const ts_image_limits *limits, ts_movie_info *info, char *err) {
  if (path == nullptr || *path == '\0') return ts_error(err, TS_EINVAL, "no movie file name given");
  return ts_guard(path, err, [&] { return ts_movie_probe_(path, limits, info, err); });
}

extern "C" int ts_movie_read(const char *path, long first, long last, const ts_image_limits *limits,
                             ts_movie_frame_fn each, void *ctx, char *err) {
  if (path == nullptr || *path == '\0') return ts_error(err, TS_EINVAL, "no movie file name given");
  return ts_guard(path, err, [&] { return ts_movie_read_(path, first, last, limits, each, ctx, err); });
}

/* --- animations ------------------------------------------------------------ */

static int ts_write_animation_(const char *path, const ts_image *frames, int n, double fps, char *err) {
  if (n < 1) return ts_error(err, TS_EINVAL, "%s: no frames to write", path);
  for (int k = 0; k < n; k++) {
    int rc = ts_check_image(path, &frames[k], err);
    if (rc != 0) return rc;
    if (frames[k].width != frames[0].width || frames[k].height != frames[0].height ||
        frames[k].channels != frames[0].channels || frames[k].type != frames[0].type)
      return ts_error(err, TS_EINVAL, "%s: frame %d differs from frame 0 in size, channels or type", path, k);
  }
  ts_tmpfile tmp;
  tmp.path =
      std::string(path) + ".tmp-" + std::to_string(getpid()) + "-" + std::to_string(ts_tmp_seq++);
  auto out = ImageOutput::create(path);
  if (!out) return ts_error(err, TS_EINVAL, "%s: no image format for this file name; use .gif", path);
  if (!out->supports("multiimage") || !out->supports("appendsubimage"))
    return ts_error(err, TS_EINVAL, "%s: %s holds no animation; use .gif", path, out->format_name());
  const ts_image &f0 = frames[0];
  ImageSpec spec(f0.width, f0.height, f0.channels, ts_oiio_type(f0.type));
  ts_out_channel_names(spec);
  int num = (int)(fps * 1000.0 + 0.5);
  spec.attribute("FramesPerSecond", TypeDesc::TypeRational, std::vector<int>{num > 0 ? num : 1, 1000}.data());
  spec.attribute("oiio:LoopCount", 0); /* loop forever */
  std::vector<ImageSpec> specs((size_t)n, spec);
  OIIO::stride_t xstride = (OIIO::stride_t)(f0.channels * ts_pixtype_size(f0.type));
  std::string why;
  bool ok = out->open(tmp.path, n, specs.data());
  for (int k = 0; ok && k < n; k++) {
    ok = (k == 0 || out->open(tmp.path, specs[(size_t)k], ImageOutput::AppendSubimage)) &&
         out->write_image(ts_oiio_type(f0.type), frames[k].pixels, xstride, xstride * f0.width);
  }
  ok = out->close() && ok;
  if (!ok) why = ts_oneline(out->geterror());
  ok = ok && ts_sync(tmp.path.c_str(), why) == 0;
  if (ok && rename(tmp.path.c_str(), path) != 0) {
    why = strerror(errno);
    ok = false;
  }
  if (!ok) return ts_error(err, TS_EIO, "%s: cannot write the animation: %s", path, why.c_str());
  tmp.keep = true;
  return 0;
}

extern "C" int ts_image_write_animation(const char *path, const ts_image *frames, int n, double fps, char *err) {
  if (path == nullptr || *path == '\0') return ts_error(err, TS_EINVAL, "no output file name given");
  try {
    ts_oiio_errscope scope;
    return ts_write_animation_(path, frames, n, fps, err);
  } catch (const std::bad_alloc &) {
    return ts_error(err, TS_ENOMEM, "%s: out of memory writing the animation", path);
  } catch (...) {
    return ts_error(err, TS_EIO, "%s: cannot write the animation", path);
  }
}

/* --- large images by regions ------------------------------------------------ *
 *
 * A reader keeps the file open and reads whole rows on demand (OpenImageIO
 * reads a tiled file's tiles for them); a writer is ts_write spread over
 * calls: a temporary name, bands in order, then sync and rename. */

struct ts_image_regions {
  std::string name;
  ts_input io;
  ts_pixtype type; /* of the samples read: U8, U16 or F32 */
  std::vector<unsigned char> rows; /* scratch for reads narrower than the image */
};

static int ts_regions_open_(const char *path, const ts_image_limits *limits, ts_image_info *info, ts_meta **meta,
                            ts_image_regions **out, char *err) {
  std::unique_ptr<ts_image_regions> r(new ts_image_regions);
  r->name = path;
  ts_image_src src{path, path, nullptr, 0};
  int rc = ts_open(src, limits, r->io, err);
  if (rc != 0) return rc;
  const ImageSpec &spec = r->io.in->spec();
  r->type = ts_spec_type(spec);
  if (r->type == TS_PIX_F16) r->type = TS_PIX_F32;
  *info = ts_image_info{spec.width, spec.height, spec.nchannels, r->type};
  if (meta != nullptr) {
    std::unique_ptr<ts_meta> m(new ts_meta);
    m->attribs = spec.extra_attribs;
    if (OIIO::Strutil::iequals(r->io.in->format_name(), "tiff")) {
      ts_file f(ts_image_src_open(&src));
      if (f) ts_geo_read_attrs(f.get(), m->attribs);
    }
    *meta = m.release();
  }
  *out = r.release();
  return 0;
}

/* Rows [y, y + h) of channel 0 into dst (the whole width). */
static int ts_regions_rows(ts_image_regions *r, int y, int h, void *dst, char *err) {
  bool ok = r->io.in->read_scanlines(0, 0, y, y + h, 0, 0, 1, ts_oiio_type(r->type), dst);
  std::string reason = r->io.in->geterror();
  if (!ok || !reason.empty())
    return ts_error(err, TS_EFORMAT, "%s: unreadable or truncated image at rows %d..%d: %s", r->name.c_str(), y,
                    y + h - 1, ts_oneline(reason).c_str());
  return 0;
}

/* Rows at a time when the region is narrower than the image: the scratch
 * holds at most this many bytes (or one row). */
#define TS_REGION_SCRATCH (16u << 20)

static int ts_regions_read_(ts_image_regions *r, int x, int y, int w, int h, void *dst, char *err) {
  const ImageSpec &spec = r->io.in->spec();
  if (x < 0 || y < 0 || w < 1 || h < 1 || x > spec.width - w || y > spec.height - h)
    return ts_error(err, TS_EINVAL, "%s: region %dx%d at (%d, %d) outside the %dx%d image", r->name.c_str(), w, h,
                    x, y, spec.width, spec.height);
  size_t px = ts_pixtype_size(r->type), row = (size_t)spec.width * px;
  if (x == 0 && w == spec.width) return ts_regions_rows(r, y, h, dst, err);
  int chunk = (int)std::max<size_t>(1, TS_REGION_SCRATCH / row);
  for (int y0 = 0; y0 < h; y0 += chunk) {
    int n = std::min(chunk, h - y0);
    r->rows.resize(row * (size_t)n);
    int rc = ts_regions_rows(r, y + y0, n, r->rows.data(), err);
    if (rc != 0) return rc;
    for (int j = 0; j < n; j++)
      memcpy((unsigned char *)dst + ((size_t)(y0 + j) * (size_t)w) * px, r->rows.data() + (size_t)j * row + (size_t)x * px,
             (size_t)w * px);
  }
  return 0;
}

extern "C" int ts_image_regions_open(const char *path, const ts_image_limits *limits, ts_image_info *info,
                                     ts_meta **meta, ts_image_regions **out, char *err) {
  *out = nullptr;
  if (meta != nullptr) *meta = nullptr;
  if (path == nullptr || *path == '\0') return ts_error(err, TS_EINVAL, "no image file name given");
  return ts_guard(path, err, [&] { return ts_regions_open_(path, limits, info, meta, out, err); });
}

extern "C" int ts_image_regions_read(ts_image_regions *r, int x, int y, int w, int h, void *dst, char *err) {
  return ts_guard(r->name.c_str(), err, [&] { return ts_regions_read_(r, x, y, w, h, dst, err); });
}

extern "C" void ts_image_regions_close(ts_image_regions *r) { delete r; }

struct ts_image_writer {
  ts_tmpfile tmp; /* declared first: removed after the writer is closed */
  std::string path, fmt;
  std::vector<unsigned char> bytes; /* PNG and JPEG, encoded in memory (ts_write_file) */
  std::unique_ptr<OIIO::Filesystem::IOVecOutput> sink;
  std::unique_ptr<ImageOutput> out;
  ParamValueList geo; /* GeoTIFF tags to append to a TIFF */
  int w = 0, h = 0, channels = 0, next_y = 0;
  bool tiled = false, open = false;
};

/* Classic TIFF offsets are 32 bits: past this many bytes of pixels (before
 * compression, so a file near the limit never overflows) BigTIFF. */
#define TS_BIGTIFF_FROM 0xF0000000ull

static int ts_writer_create_(const char *path, int w, int h, int channels, int tile, const ts_meta *meta_from,
                             ts_image_writer **out, char *err) {
  if (w < 1 || h < 1 || channels < 1 || channels > TS_IMAGE_MAX_CHANNELS || tile < 16 || tile % 16 != 0)
    return ts_error(err, TS_EINVAL, "%s: cannot write a %dx%d image of %d channels in %d-pixel tiles", path, w, h,
                    channels, tile);
  std::unique_ptr<ts_image_writer> wr(new ts_image_writer);
  wr->path = path;
  wr->tmp.path = wr->path + ".tmp-" + std::to_string(getpid()) + "-" + std::to_string(ts_tmp_seq++);
  wr->out = ImageOutput::create(path);
  if (!wr->out)
    return ts_error(err, TS_EINVAL, "%s: no image format for this file name; use .tif, .exr, .png or .jpg", path);
  wr->fmt = wr->out->format_name();
  wr->w = w, wr->h = h, wr->channels = channels;
  ImageSpec spec(w, h, ts_out_channels(wr->fmt, channels), ts_out_type(wr->fmt, TS_PIX_U8));
  ts_out_channel_names(spec);
  if (meta_from != nullptr)
    for (const ParamValue &p : meta_from->attribs)
      if (ts_meta_passes(p.name().string())) spec.extra_attribs.add_or_replace(p);
  ts_out_defaults(wr->fmt, spec, meta_from);
  wr->tiled = (wr->fmt == "tiff" || wr->fmt == "openexr") && wr->out->supports("tiles");
  if (wr->tiled) {
    spec.tile_width = spec.tile_height = tile;
    spec.tile_depth = 1;
  }
  if (wr->fmt == "tiff" && (uint64_t)w * (uint64_t)h * (uint64_t)channels >= TS_BIGTIFF_FROM)
    spec.attribute("tiff:bigtiff", 1);
  if (wr->fmt == "tiff" && meta_from != nullptr && ts_has_geo(meta_from->attribs)) wr->geo = meta_from->attribs;
  bool in_memory = wr->fmt == "png" || wr->fmt == "jpeg";
  if (in_memory) wr->sink.reset(new OIIO::Filesystem::IOVecOutput(wr->bytes));
  if ((in_memory && !wr->out->set_ioproxy(wr->sink.get())) || !wr->out->open(wr->tmp.path, spec))
    return ts_error(err, TS_EIO, "%s: cannot write image: %s", path, ts_oneline(wr->out->geterror()).c_str());
  wr->open = true;
  *out = wr.release();
  return 0;
}

static int ts_writer_put_(ts_image_writer *wr, int y, int h, const uint8_t *px, char *err) {
  if (y != wr->next_y || h < 1 || h > wr->h - y)
    return ts_error(err, TS_EINVAL, "%s: rows %d..%d written out of order (next: row %d of %d)", wr->path.c_str(), y,
                    y + h - 1, wr->next_y, wr->h);
  OIIO::stride_t xs = wr->channels;
  bool ok = wr->tiled ? wr->out->write_tiles(0, wr->w, y, y + h, 0, 1, TypeDesc::UINT8, px, xs, xs * wr->w)
                      : wr->out->write_scanlines(y, y + h, 0, TypeDesc::UINT8, px, xs, xs * wr->w);
  if (!ok)
    return ts_error(err, TS_EIO, "%s: cannot write rows %d..%d: %s", wr->path.c_str(), y, y + h - 1,
                    ts_oneline(wr->out->geterror()).c_str());
  wr->next_y = y + h;
  return 0;
}

static int ts_writer_finish_(ts_image_writer *wr, char *err) {
  if (wr->next_y != wr->h)
    return ts_error(err, TS_EINVAL, "%s: finished at row %d of %d", wr->path.c_str(), wr->next_y, wr->h);
  std::string why;
  bool ok = wr->out->close();
  wr->open = false;
  if (!ok) why = ts_oneline(wr->out->geterror());
  if (ok && wr->sink && ts_write_file(wr->tmp.path, wr->bytes, why) != 0) ok = false;
  if (ok && !wr->geo.empty()) ok = ts_geo_write_attrs(wr->tmp.path.c_str(), wr->geo, why);
  ok = ok && ts_sync(wr->tmp.path.c_str(), why) == 0;
  if (ok && rename(wr->tmp.path.c_str(), wr->path.c_str()) != 0) {
    why = strerror(errno);
    ok = false;
  }
  if (!ok) return ts_error(err, TS_EIO, "%s: cannot write image: %s", wr->path.c_str(), why.c_str());
  wr->tmp.keep = true;
  return 0;
}

/* Writer calls behind the C boundary: exceptions become TS_EIO. */
template <typename F>
static int ts_guard_write(const char *path, char *err, F body) {
  try {
    ts_oiio_errscope scope;
    return body();
  } catch (const std::bad_alloc &) {
    return ts_error(err, TS_ENOMEM, "%s: out of memory writing the image", path);
  } catch (const std::exception &e) {
    return ts_error(err, TS_EIO, "%s: cannot write image: %s", path, ts_oneline(e.what()).c_str());
  } catch (...) {
    return ts_error(err, TS_EIO, "%s: cannot write image", path);
  }
}

extern "C" int ts_image_writer_create(const char *path, int w, int h, int channels, int tile,
                                      const ts_meta *meta_from, ts_image_writer **out, char *err) {
  *out = nullptr;
  if (path == nullptr || *path == '\0') return ts_error(err, TS_EINVAL, "no output file name given");
  return ts_guard_write(path, err, [&] { return ts_writer_create_(path, w, h, channels, tile, meta_from, out, err); });
}

extern "C" int ts_image_writer_put(ts_image_writer *wr, int y, int h, const uint8_t *px, char *err) {
  return ts_guard_write(wr->path.c_str(), err, [&] { return ts_writer_put_(wr, y, h, px, err); });
}

extern "C" void ts_image_writer_abort(ts_image_writer *wr) {
  if (wr == nullptr) return;
  try {
    if (wr->open) wr->out->close();
  } catch (...) {
  }
  delete wr;
}

extern "C" int ts_image_writer_finish(ts_image_writer *wr, char *err) {
  int rc = ts_guard_write(wr->path.c_str(), err, [&] { return ts_writer_finish_(wr, err); });
  ts_image_writer_abort(wr);
  return rc;
}

/* --- the library's one export -------------------------------------------- */

extern "C" __attribute__((visibility("default"))) const ts_image_lib TS_IMAGE_LIB_TABLE = {
    ts_image_read, ts_image_read_mem, ts_image_probe_mem, ts_image_write,
    ts_meta_get,   ts_meta_set,       ts_meta_free,       ts_meta_copy,
    ts_movie_probe, ts_movie_read,    ts_image_write_animation,
    ts_image_regions_open, ts_image_regions_read, ts_image_regions_close,
    ts_image_writer_create, ts_image_writer_put, ts_image_writer_finish, ts_image_writer_abort};
