/* pool.c - see pool.h. */
#include "pool.h"

#include <pthread.h>
#include <stdlib.h>

#include "error.h"

struct ts_pool {
  int n;
  pthread_t *threads;
  pthread_mutex_t run_mu; /* one run at a time: callers on other threads wait */
  pthread_mutex_t mu;
  pthread_cond_t start, done;
  ts_pool_fn *fn;
  void *arg;
  unsigned long generation; /* bumped per run; workers wait for a new one */
  int pending;              /* workers still running the current job */
  int quit;
};

typedef struct {
  ts_pool *pool;
  int index;
} worker_arg;

static void *worker_main(void *p) {
  worker_arg *wa = p;
  ts_pool *pool = wa->pool;
  int index = wa->index;
  free(wa);
  unsigned long seen = 0;
  pthread_mutex_lock(&pool->mu);
  for (;;) {
    while (!pool->quit && pool->generation == seen) pthread_cond_wait(&pool->start, &pool->mu);
    if (pool->quit) break;
    seen = pool->generation;
    ts_pool_fn *fn = pool->fn;
    void *arg = pool->arg;
    pthread_mutex_unlock(&pool->mu);
    fn(arg, index, pool->n);
    pthread_mutex_lock(&pool->mu);
    if (--pool->pending == 0) pthread_cond_signal(&pool->done);
  }
  pthread_mutex_unlock(&pool->mu);
  return NULL;
}

int ts_pool_create(ts_pool **out, int nthreads) {
  *out = NULL;
  if (nthreads < 1) return TS_EINVAL;
  ts_pool *pool = calloc(1, sizeof(*pool));
  if (pool == NULL) return TS_ENOMEM;
  pool->n = nthreads;
  pool->threads = calloc((size_t)nthreads, sizeof(pthread_t));
  if (pool->threads == NULL) {
    free(pool);
    return TS_ENOMEM;
  }
  pthread_mutex_init(&pool->run_mu, NULL);
  pthread_mutex_init(&pool->mu, NULL);
  pthread_cond_init(&pool->start, NULL);
  pthread_cond_init(&pool->done, NULL);
  for (int i = 1; i < nthreads; i++) {
    worker_arg *wa = malloc(sizeof(*wa));
    if (wa == NULL || (wa->pool = pool, wa->index = i,
                       pthread_create(&pool->threads[i], NULL, worker_main, wa) != 0)) {
      free(wa);
      pool->n = i; /* only threads 1..i-1 exist */
      ts_pool_destroy(pool);
      return TS_ENOMEM;
    }
  }
  *out = pool;
  return 0;
}

int ts_pool_size(const ts_pool *pool) { return pool->n; }

void ts_pool_run(ts_pool *pool, ts_pool_fn *fn, void *arg) {
  if (pool->n == 1) {
    fn(arg, 0, 1);
    return;
  }
  pthread_mutex_lock(&pool->run_mu);
  pthread_mutex_lock(&pool->mu);
  pool->fn = fn;
  pool->arg = arg;
  pool->pending = pool->n - 1;
  pool->generation++;
  pthread_cond_broadcast(&pool->start);
  pthread_mutex_unlock(&pool->mu);
  fn(arg, 0, pool->n);
  pthread_mutex_lock(&pool->mu);
  while (pool->pending > 0) pthread_cond_wait(&pool->done, &pool->mu);
  pthread_mutex_unlock(&pool->mu);
  pthread_mutex_unlock(&pool->run_mu);
}

void ts_pool_destroy(ts_pool *pool) {
  if (pool == NULL) return;
  pthread_mutex_lock(&pool->mu);
  pool->quit = 1;
  pthread_cond_broadcast(&pool->start);
  pthread_mutex_unlock(&pool->mu);
  for (int i = 1; i < pool->n; i++) pthread_join(pool->threads[i], NULL);
  pthread_mutex_destroy(&pool->mu);
  pthread_mutex_destroy(&pool->run_mu);
  pthread_cond_destroy(&pool->start);
  pthread_cond_destroy(&pool->done);
  free(pool->threads);
  free(pool);
}
