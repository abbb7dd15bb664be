/* http_auth.h - the operations page's key check (README, "Operations
 * page"; SECURITY.md). With keys, a request proves a page key or an admin
 * key (the whole line of its file, or the --secret-file's secret) in its
 * Authorization header, either as HTTP Basic auth (any user name, the key
 * as password: what a browser's login box sends) or as "Bearer KEY" (what
 * Prometheus' `authorization` setting sends). Client and worker keys are
 * refused: they open the data plane, which the page must not expose. The
 * comparison is constant-time and tells nothing of the key's length. */
#ifndef TS_HTTP_AUTH_H
#define TS_HTTP_AUTH_H

#include "auth.h"

#define TS_HTTP_AUTH_HEADER_MAX 4096 /* longer headers are refused unread */

/* 0 if header (the Authorization value; NULL when absent) proves a page
 * or admin key of a (its ring, else its own key), else TS_EAUTH and the
 * reason in err. a must have a secret. */
int ts_http_auth_check(const ts_auth *a, const char *header, char *err);

#endif
