/* test_pool.c - the thread pool (pool.h) run from several threads at once,
 * as a tiled scene's tile threads and concurrent jobs do: every run sees
 * every worker exactly once with its own argument, whoever else runs. */
#include <pthread.h>

#include "pool.h"
#include "ts_test.h"

#define RUNS 2000
#define CALLERS 3

typedef struct {
  int hits[8]; /* per worker index: calls of this run */
  int n;       /* the worker count the calls were told */
} run_arg;

static void count(void *arg, int worker, int nworkers) {
  run_arg *r = arg;
  r->hits[worker]++; /* each worker index once per run: no two writers */
  if (worker == 0) r->n = nworkers;
}

typedef struct {
  ts_pool *pool;
  int bad; /* runs whose calls were not one per worker */
} caller;

static void *call_runs(void *arg) {
  caller *c = arg;
  for (int i = 0; i < RUNS; i++) {
    run_arg r = {{0}, 0};
    ts_pool_run(c->pool, count, &r);
    for (int w = 0; w < 8; w++)
      if (r.hits[w] != (w < r.n ? 1 : 0)) c->bad++;
  }
  return NULL;
}

static void runs_from_several_threads_take_turns(void **state) {
  (void)state;
  ts_pool *pool;
  assert_int_equal(ts_pool_create(&pool, 4), 0);
  caller c[CALLERS];
  pthread_t th[CALLERS];
  for (int i = 0; i < CALLERS; i++) {
    c[i] = (caller){pool, 0};
    assert_int_equal(pthread_create(&th[i], NULL, call_runs, &c[i]), 0);
  }
  for (int i = 0; i < CALLERS; i++) {
    pthread_join(th[i], NULL);
    assert_int_equal(c[i].bad, 0);
  }
  ts_pool_destroy(pool);
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(runs_from_several_threads_take_turns),
};

TS_TEST_MAIN(tests)
