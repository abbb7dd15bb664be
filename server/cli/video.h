/* video.h - `texsyn video`: a sequence stylized from painted keyframes, as
 * chains of stylize jobs along the optical flow (video_chain.h), blended
 * between keys. */
#ifndef TS_CLI_VIDEO_H
#define TS_CLI_VIDEO_H

/* The command, argv[0] being "video": the process exit status. */
int ts_cmd_video(int argc, char **argv);

#endif
