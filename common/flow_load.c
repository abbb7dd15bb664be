/* flow_load.c - flow.h's OpenCV function in the programs: loads
 * libtexsyn-flow.so on first use and forwards through its table
 * (flow_lib.h says why the flow is a library of its own, dl_lib.h where it
 * is looked for). */
#include "dl_lib.h"
#include "error.h"
#include "flow.h"
#include "flow_lib.h"

static ts_dl_lib flow_lib = {TS_FLOW_LIB_NAME, TS_FLOW_LIB_ENV, TS_FLOW_LIB_TABLE_NAME, "optical flow library"};
/* The table, valid once ts_flow_lib_load returned 0. */
#define flow_table ((const ts_flow_lib *)flow_lib.table)

int ts_flow_lib_load(char *err) { return ts_dl_lib_load(&flow_lib, err); }

int ts_flow_dis(const uint8_t *from, const uint8_t *to, int w, int h, float *uv, char *err) {
  int rc = ts_flow_lib_load(err);
  return rc != 0 ? rc : flow_table->dis(from, to, w, h, uv, err);
}

const char *ts_flow_method(void) { return ts_flow_lib_load(NULL) == 0 ? flow_table->method() : ""; }
