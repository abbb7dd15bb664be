/* stylize.h - `texsyn stylize`: paint a target in the style of an
 * exemplar, guided by image pairs (server/engines/stylit.h); and its
 * quality tools, `texsyn energy` and `texsyn apply-nnf`. */
#ifndef TS_CLI_STYLIZE_H
#define TS_CLI_STYLIZE_H

/* The command, argv[0] being "stylize": the process exit status. */
int ts_cmd_stylize(int argc, char **argv);
/* `texsyn energy`: a stylized image's score (stylit.h). */
int ts_cmd_energy(int argc, char **argv);
/* `texsyn apply-nnf`: a saved NNF voted over another layer. */
int ts_cmd_apply_nnf(int argc, char **argv);

#endif
