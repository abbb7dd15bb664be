/* segment.h - `texsyn segment`: label every pixel of an image with the
 * class of the most similar training texture (server/engines/segment.h). */
#ifndef TS_CLI_SEGMENT_H
#define TS_CLI_SEGMENT_H

/* The command, argv[0] being "segment": the process exit status. */
int ts_cmd_segment(int argc, char **argv);

#endif
