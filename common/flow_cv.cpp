/* flow_cv.cpp - ts_flow_dis through OpenCV's DIS optical flow; built into
 * libtexsyn-flow.so, whose one exported symbol is the table at the end
 * (flow_lib.h). Like image_oiio.cpp, a thin shim: OpenCV's types and
 * exceptions stay on this side of the extern "C" boundary; every entry
 * point catches everything and answers with a TS_E* code and one line.
 *
 * Determinism, the product's first promise, costs three settings made once
 * per process before the first flow:
 *  - cv::setNumThreads(1): DIS cuts the patch search into one stripe per
 *    OpenCV thread and propagates good vectors along each stripe, so the
 *    flow depends on the thread count, i.e. on the machine's cores. One
 *    thread gives one answer everywhere (texsyn spreads frames over its
 *    own threads and workers instead).
 *  - cv::setUseOptimized(false): OpenCV picks SSE4.1, AVX2 or AVX-512
 *    variants of its kernels at run time by the CPU; they round
 *    differently, so a Zen 4, a Zen 5 and an Intel machine would disagree
 *    in the last bits. Off, only the x86-64 baseline code (SSE2) runs,
 *    the same on every machine. It also turns off IPP.
 *  - cv::ocl::setUseOpenCL(false): no GPU kernels, whatever is installed.
 * These are process-wide: in texsyn nothing else calls OpenCV, and the
 * settings are what every flow needs anyway. And each call starts afresh,
 * a new DIS object writing into an empty field: an object used before, or
 * a field holding an earlier flow, gives other bytes (measured: the same
 * pair through one object four times gave four different flows).
 *
 * The DIS parameters are set one by one rather than left to a preset, so
 * that a later OpenCV changing its presets cannot change our flows
 * unnoticed; the values are OpenCV 4.6's PRESET_MEDIUM.
 *
 * Measured on a 256x256 pair cut from aero1.jpg (AMD EPYC with AVX-512, one
 * thread, the best of 200 alternating runs): 5.9 ms without the optimized
 * code, 5.9 ms with it; the flows were the same bytes on that machine, so
 * here setUseOptimized(false) costs nothing measurable and insures against
 * the machines where the dispatched code would round differently. */
#include <cstdio>
#include <cstring>
#include <exception>
#include <new>
#include <string>

#include <opencv2/core.hpp>
#include <opencv2/core/ocl.hpp>
#include <opencv2/core/utility.hpp>
#include <opencv2/video/tracking.hpp>

extern "C" {
#include "error.h"
#include "flow.h"
}
#include "flow_lib.h"

namespace {

/* The DIS parameters (see the file comment). */
constexpr int kFinestScale = 1;  /* the flow is computed at half size, then upscaled */
constexpr int kPatchSize = 8;
constexpr int kPatchStride = 3;
constexpr int kDescentIterations = 25;
constexpr int kRefinementIterations = 5;
constexpr float kAlpha = 20.0f; /* smoothness */
constexpr float kDelta = 5.0f;  /* colour constancy */
constexpr float kGamma = 10.0f; /* gradient constancy */

/* One line, as err holds. */
std::string oneline(std::string s) {
  for (char &ch : s)
    if (ch == '\n' || ch == '\r') ch = ' ';
  return s.empty() ? std::string("no reason given") : s;
}

void setup_once() {
  static const bool done = [] {
    cv::setNumThreads(1);
    cv::setUseOptimized(false);
    cv::ocl::setUseOpenCL(false);
    return true;
  }();
  (void)done;
}

cv::Ptr<cv::DISOpticalFlow> make_dis() {
  cv::Ptr<cv::DISOpticalFlow> dis = cv::DISOpticalFlow::create(cv::DISOpticalFlow::PRESET_MEDIUM);
  dis->setFinestScale(kFinestScale);
  dis->setPatchSize(kPatchSize);
  dis->setPatchStride(kPatchStride);
  dis->setGradientDescentIterations(kDescentIterations);
  dis->setVariationalRefinementIterations(kRefinementIterations);
  dis->setVariationalRefinementAlpha(kAlpha);
  dis->setVariationalRefinementDelta(kDelta);
  dis->setVariationalRefinementGamma(kGamma);
  dis->setUseMeanNormalization(true);
  dis->setUseSpatialPropagation(true);
  return dis;
}

int flow_dis(const uint8_t *from, const uint8_t *to, int w, int h, float *uv, char *err) {
  if (w < TS_FLOW_MIN_SIDE || h < TS_FLOW_MIN_SIDE)
    return ts_error(err, TS_EINVAL, "optical flow needs frames of at least %dx%d pixels, not %dx%d",
                    TS_FLOW_MIN_SIDE, TS_FLOW_MIN_SIDE, w, h);
  try {
    setup_once();
    /* Headers on the caller's bytes: nothing is copied in. */
    const cv::Mat a(h, w, CV_8UC1, const_cast<uint8_t *>(from));
    const cv::Mat b(h, w, CV_8UC1, const_cast<uint8_t *>(to));
    cv::Mat flow;
    make_dis()->calc(a, b, flow);
    if (flow.rows != h || flow.cols != w || flow.type() != CV_32FC2 || !flow.isContinuous())
      return ts_error(err, TS_EIO, "OpenCV's DIS flow gave a %dx%d field of type %d, not %dx%d of CV_32FC2",
                      flow.cols, flow.rows, flow.type(), w, h);
    memcpy(uv, flow.ptr<float>(), sizeof(float) * 2 * (size_t)w * (size_t)h);
    return 0;
  } catch (const std::bad_alloc &) {
    return ts_error(err, TS_ENOMEM, "out of memory computing the optical flow of %dx%d frames", w, h);
  } catch (const std::exception &e) {
    return ts_error(err, TS_EIO, "OpenCV's DIS flow failed on %dx%d frames: %s", w, h, oneline(e.what()).c_str());
  } catch (...) {
    return ts_error(err, TS_EIO, "OpenCV's DIS flow failed on %dx%d frames", w, h);
  }
}

const char *flow_method() {
  static const std::string line = [] {
    char buf[256];
    snprintf(buf, sizeof(buf),
             "OpenCV %s DIS (finest scale %d, patch %d, stride %d, %d descent and %d refinement iterations, "
             "alpha %g, delta %g, gamma %g; one thread, baseline code)",
             cv::getVersionString().c_str(), kFinestScale, kPatchSize, kPatchStride, kDescentIterations, kRefinementIterations,
             kAlpha, kDelta, kGamma);
    return std::string(buf);
  }();
  return line.c_str();
}

}  // namespace

extern "C" __attribute__((visibility("default"))) const ts_flow_lib TS_FLOW_LIB_TABLE = {flow_dis, flow_method};
