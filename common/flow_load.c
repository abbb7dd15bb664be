/* flow_load.c - flow.h's OpenCV function in the programs: loads
 * libtexsyn-flow.so on first use and forwards through its table
 * (flow_lib.h says why the flow is a library of its own, dl_lib.h where it
 * is looked for). */
#include <pthread.h>

#include "dl_lib.h"
#include "error.h"
#include "flow.h"
#include "flow_lib.h"

/* The outcome of the one load, written only by flow_load_once. */
static pthread_once_t flow_once = PTHREAD_ONCE_INIT;
static const ts_flow_lib *flow_lib;
static int flow_rc;
static char flow_err[TS_ERR_LEN];

static void flow_load_once(void) {
  static const ts_dl_lib lib = {TS_FLOW_LIB_NAME, TS_FLOW_LIB_ENV, TS_FLOW_LIB_TABLE_NAME,
                                "optical flow library"};
  const void *table = NULL;
  flow_rc = ts_dl_lib_open(&lib, &table, flow_err);
  flow_lib = table;
}

int ts_flow_lib_load(char *err) {
  pthread_once(&flow_once, flow_load_once);
  return flow_rc != 0 ? ts_error(err, flow_rc, "%s", flow_err) : 0;
}

int ts_flow_dis(const uint8_t *from, const uint8_t *to, int w, int h, float *uv, char *err) {
  int rc = ts_flow_lib_load(err);
  return rc != 0 ? rc : flow_lib->dis(from, to, w, h, uv, err);
}

const char *ts_flow_method(void) { return ts_flow_lib_load(NULL) == 0 ? flow_lib->method() : ""; }
