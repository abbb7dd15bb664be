/* keyring.h - the coordinator's keys (SECURITY.md).
 *
 * Every key a peer may prove: the --secret-file (an admin key unless it is
 * a typed key of another kind) and every *.key file of the --keys
 * directory (typed keys only: "texsyn:KIND:NAME:HEX", auth.h). A peer
 * names the key it uses; the coordinator looks it up by kind and name.
 * Several keys may share a kind and name: both are accepted, which is how
 * a key is rotated (add the new file, SIGHUP, hand it out, remove the old
 * one, SIGHUP) without stopping a job. Reloading swaps the whole table
 * under a lock, and a table that fails to load leaves the old one in use. */
#ifndef TS_KEYRING_H
#define TS_KEYRING_H

#include <stddef.h>
#include <stdint.h>

#include "auth.h"

#define TS_KEYRING_MAX 4096         /* keys in a table */
#define TS_KEYRING_SAME_NAME_MAX 8  /* keys of one kind and name (rotation) */

/* Creates a table from secret_file and dir (either may be NULL) and
 * remembers them for ts_keyring_reload. */
int ts_keyring_create(ts_keyring **out, const char *secret_file, const char *dir, char *err);
void ts_keyring_destroy(ts_keyring *r);
/* Reads the files again; on failure the table in use stays. */
int ts_keyring_reload(ts_keyring *r, char *err);
/* Keys per kind (counts[TS_KEY_ADMIN..TS_KEY_PAGE]; counts[0] unused). */
void ts_keyring_counts(ts_keyring *r, uint32_t counts[5]);
/* Copies up to max keys of this kind and name into out; their number. */
int ts_keyring_find(ts_keyring *r, uint8_t kind, const char *name, ts_auth *out, int max);
/* 1 and *who if token (n bytes) is a whole key of one of the kinds in
 * kinds (a bit per TS_KEY_*), compared in constant time with each. */
int ts_keyring_match(ts_keyring *r, const void *token, size_t n, unsigned kinds, ts_principal *who);

#endif
