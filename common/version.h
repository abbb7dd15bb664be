/* version.h - the texsyn release, which `--version` of every program
 * prints with the wire protocol version it speaks (proto/frame.h). Raise it
 * with every release; peers of another protocol version refuse each other,
 * peers of another release of the same protocol work together. */
#ifndef TS_VERSION_H
#define TS_VERSION_H

#define TS_VERSION "0.1.0"

#endif
