/* stylize.h - `texsyn stylize`: paint a target in the style of an
 * exemplar, guided by image pairs (server/engines/stylit.h). */
#ifndef TS_CLI_STYLIZE_H
#define TS_CLI_STYLIZE_H

/* The command, argv[0] being "stylize": the process exit status. */
int ts_cmd_stylize(int argc, char **argv);

#endif
