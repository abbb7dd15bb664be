/* keyring.c - see keyring.h. */
#include "keyring.h"

#include <dirent.h>
#include <errno.h>
#include <pthread.h>
#include <sodium.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>

#include "error.h"

typedef struct {
  ts_auth key;
  int64_t mtime_ns; /* the file's: the newest of a name is the one a dial uses */
} ring_key;

struct ts_keyring {
  pthread_mutex_t lock;
  ring_key *keys;
  int n;
  char *secret_file, *dir;
};

static void keys_free(ring_key *k, int n) {
  if (k == NULL) return;
  sodium_memzero(k, sizeof(*k) * (size_t)n);
  free(k);
}

static int64_t mtime_of(const char *path) {
  struct stat sb;
  if (stat(path, &sb) != 0) return 0;
  return (int64_t)sb.st_mtim.tv_sec * 1000000000 + sb.st_mtim.tv_nsec;
}

static int add_file(ring_key **keys, int *n, const char *path, int typed_only, char *err) {
  if (*n >= TS_KEYRING_MAX) return ts_error(err, TS_ETOOBIG, "more than %d keys", TS_KEYRING_MAX);
  ring_key *k = realloc(*keys, sizeof(*k) * (size_t)(*n + 1));
  if (k == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  *keys = k;
  int rc = ts_auth_load(&k[*n].key, path, err);
  if (rc == 0 && typed_only && memcmp(k[*n].key.secret, TS_AUTH_KEY_PREFIX, strlen(TS_AUTH_KEY_PREFIX)) != 0)
    rc = ts_error(err, TS_EINVAL,
                  "%s is not a typed key (texsyn:KIND:NAME:HEX); only --secret-file takes a plain shared secret; "
                  "make keys with: texsyn-server --gen-secret KIND PATH",
                  path);
  if (rc != 0) {
    sodium_memzero(&k[*n], sizeof(k[*n]));
    return rc;
  }
  k[*n].mtime_ns = mtime_of(path);
  (*n)++;
  return 0;
}

/* Every *.key in dir (names starting with '.' skipped: editors' and
 * Kubernetes' own files). */
static int add_dir(ring_key **keys, int *n, const char *dir, char *err) {
  DIR *d = opendir(dir);
  if (d == NULL) return ts_error(err, TS_EIO, "cannot read the --keys directory %s: %s", dir, strerror(errno));
  int rc = 0;
  struct dirent *e;
  while (rc == 0 && (e = readdir(d)) != NULL) {
    size_t len = strlen(e->d_name);
    if (e->d_name[0] == '.' || len < 5 || strcmp(e->d_name + len - 4, ".key") != 0) continue;
    char path[4096];
    if (snprintf(path, sizeof(path), "%s/%s", dir, e->d_name) >= (int)sizeof(path))
      rc = ts_error(err, TS_EINVAL, "%s/%s: path too long", dir, e->d_name);
    else rc = add_file(keys, n, path, 1, err);
  }
  closedir(d);
  return rc;
}

static int newest_first(const void *pa, const void *pb) {
  const ring_key *a = pa, *b = pb;
  return a->mtime_ns < b->mtime_ns ? 1 : a->mtime_ns > b->mtime_ns ? -1 : 0;
}

static int load(const ts_keyring *r, ring_key **out, int *nout, char *err) {
  ring_key *keys = NULL;
  int n = 0, rc = 0;
  if (r->secret_file != NULL) rc = add_file(&keys, &n, r->secret_file, 0, err);
  if (rc == 0 && r->dir != NULL) rc = add_dir(&keys, &n, r->dir, err);
  if (rc == 0 && n == 0) rc = ts_error(err, TS_EINVAL, "the --keys directory %s holds no *.key file", r->dir);
  if (rc != 0) {
    keys_free(keys, n);
    return rc;
  }
  qsort(keys, (size_t)n, sizeof(*keys), newest_first);
  *out = keys;
  *nout = n;
  return 0;
}

int ts_keyring_create(ts_keyring **out, const char *secret_file, const char *dir, char *err) {
  ts_keyring *r = calloc(1, sizeof(*r));
  if (r == NULL) return ts_error(err, TS_ENOMEM, "out of memory");
  pthread_mutex_init(&r->lock, NULL);
  r->secret_file = secret_file ? strdup(secret_file) : NULL;
  r->dir = dir ? strdup(dir) : NULL;
  int rc = (secret_file && !r->secret_file) || (dir && !r->dir) ? ts_error(err, TS_ENOMEM, "out of memory")
                                                                 : load(r, &r->keys, &r->n, err);
  if (rc != 0) {
    ts_keyring_destroy(r);
    return rc;
  }
  *out = r;
  return 0;
}

void ts_keyring_destroy(ts_keyring *r) {
  if (r == NULL) return;
  keys_free(r->keys, r->n);
  free(r->secret_file);
  free(r->dir);
  pthread_mutex_destroy(&r->lock);
  free(r);
}

int ts_keyring_reload(ts_keyring *r, char *err) {
  ring_key *keys;
  int n;
  int rc = load(r, &keys, &n, err);
  if (rc != 0) return rc;
  pthread_mutex_lock(&r->lock);
  ring_key *old = r->keys;
  int nold = r->n;
  r->keys = keys;
  r->n = n;
  pthread_mutex_unlock(&r->lock);
  keys_free(old, nold);
  return 0;
}

void ts_keyring_counts(ts_keyring *r, uint32_t counts[5]) {
  memset(counts, 0, sizeof(uint32_t) * 5);
  pthread_mutex_lock(&r->lock);
  for (int i = 0; i < r->n; i++) counts[r->keys[i].key.who.kind]++;
  pthread_mutex_unlock(&r->lock);
}

int ts_keyring_find(ts_keyring *r, uint8_t kind, const char *name, ts_auth *out, int max) {
  int got = 0;
  pthread_mutex_lock(&r->lock);
  for (int i = 0; i < r->n && got < max; i++)
    if (r->keys[i].key.who.kind == kind && strcmp(r->keys[i].key.who.name, name) == 0) out[got++] = r->keys[i].key;
  pthread_mutex_unlock(&r->lock);
  return got;
}

int ts_keyring_match(ts_keyring *r, const void *token, size_t n, unsigned kinds, ts_principal *who) {
  int found = 0;
  pthread_mutex_lock(&r->lock);
  for (int i = 0; i < r->n; i++) {
    const ts_auth *k = &r->keys[i].key;
    if ((kinds & (1u << k->who.kind)) && ts_auth_same_secret(k, token, n) && !found) {
      found = 1;
      *who = k->who;
    }
  }
  pthread_mutex_unlock(&r->lock);
  return found;
}
