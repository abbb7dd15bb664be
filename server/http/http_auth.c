/* http_auth.c - see http_auth.h. */
#include "http_auth.h"

#include <sodium.h>
#include <string.h>
#include <strings.h>

#include "error.h"
#include "keyring.h"

/* A page key or an admin key; a client's or a worker's key is for the
 * data plane only, and one sent here (a browser, a scrape config) must not
 * be worth more than the page. */
static int page_key(const ts_auth *a, const char *given, size_t n) {
  ts_principal who;
  if (a->ring != NULL)
    return ts_keyring_match(a->ring, given, n, (1u << TS_KEY_ADMIN) | (1u << TS_KEY_PAGE), &who);
  int kind_ok = a->who.kind == 0 || a->who.kind == TS_KEY_ADMIN || a->who.kind == TS_KEY_PAGE;
  return kind_ok && ts_auth_same_secret(a, given, n);
}

/* Basic auth: base64("user:password"); the password is the secret. */
static int check_basic(const ts_auth *a, const char *b64, char *err) {
  size_t n;
  char buf[TS_HTTP_AUTH_HEADER_MAX];
  if (sodium_base642bin((unsigned char *)buf, sizeof(buf) - 1, b64, strlen(b64), NULL, &n, NULL,
                        sodium_base64_VARIANT_ORIGINAL) != 0)
    return ts_error(err, TS_EAUTH, "Authorization: Basic credentials are not valid base64");
  const char *colon = memchr(buf, ':', n);
  if (colon == NULL) {
    sodium_memzero(buf, sizeof(buf));
    return ts_error(err, TS_EAUTH, "Authorization: Basic credentials lack the ':' before the password");
  }
  size_t off = (size_t)(colon + 1 - buf);
  int ok = page_key(a, colon + 1, n - off);
  sodium_memzero(buf, sizeof(buf));
  return ok ? 0 : ts_error(err, TS_EAUTH, "wrong secret");
}

int ts_http_auth_check(const ts_auth *a, const char *header, char *err) {
  if (header == NULL)
    return ts_error(err, TS_EAUTH, "this page needs a page key or an admin key (Basic auth password or Bearer token)");
  if (strlen(header) >= TS_HTTP_AUTH_HEADER_MAX) return ts_error(err, TS_EAUTH, "Authorization header too long");
  if (strncasecmp(header, "Basic ", 6) == 0) return check_basic(a, header + 6, err);
  if (strncasecmp(header, "Bearer ", 7) == 0)
    return page_key(a, header + 7, strlen(header + 7)) ? 0 : ts_error(err, TS_EAUTH, "wrong secret");
  return ts_error(err, TS_EAUTH, "Authorization: need the Basic or Bearer scheme");
}
