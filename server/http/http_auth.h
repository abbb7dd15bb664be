/* http_auth.h - the operations page's secret check (README, "Operations
 * page"). With --secret-file, a request proves the shared secret in its
 * Authorization header, either as HTTP Basic auth (any user name, the
 * secret as password: what a browser's login box sends) or as
 * "Bearer SECRET" (what Prometheus' `authorization` setting sends). The
 * comparison is constant-time and tells nothing of the secret's length. */
#ifndef TS_HTTP_AUTH_H
#define TS_HTTP_AUTH_H

#include "auth.h"

#define TS_HTTP_AUTH_HEADER_MAX 4096 /* longer headers are refused unread */

/* 0 if header (the Authorization value; NULL when absent) proves a's
 * secret, else TS_EAUTH and the reason in err. a must have a secret. */
int ts_http_auth_check(const ts_auth *a, const char *header, char *err);

#endif
