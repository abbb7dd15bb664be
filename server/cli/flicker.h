/* flicker.h - `texsyn flicker`: how much a stylized sequence flickers, as
 * the mean temporal warp error of each frame against the previous one
 * brought along the input's optical flow (common/flow.h). */
#ifndef TS_CLI_FLICKER_H
#define TS_CLI_FLICKER_H

/* The command, argv[0] being "flicker": the process exit status. */
int ts_cmd_flicker(int argc, char **argv);

#endif
