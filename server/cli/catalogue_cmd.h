/* catalogue_cmd.h - `texsyn catalogue`: an aerial catalogue cut from an
 * orthophoto and its class map (issue 30). */
#ifndef TS_CATALOGUE_CMD_H
#define TS_CATALOGUE_CMD_H

/* The command, argv[0] being "catalogue": the process exit status. */
int ts_cmd_catalogue(int argc, char **argv);

#endif
