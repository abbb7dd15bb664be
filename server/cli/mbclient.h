/* mbclient.h - `texsyn modbus`: reads a daemon's Modbus register map
 * (proto/mbmap.h) with libmodbus and prints it by name, or sets a coil. */
#ifndef TS_MBCLIENT_H
#define TS_MBCLIENT_H

/* argv[0] is "modbus". Returns the process exit status. */
int ts_mbclient_main(int argc, char **argv);

#endif
