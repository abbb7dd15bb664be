/* pool.h - a fixed pool of threads that runs one parallel-for at a time.
 *
 * The synthesis issues thousands of small batches per level, so starting
 * threads per batch would cost more than the scan; the pool keeps them
 * parked on a condition variable. The calling thread takes part as worker 0. */
#ifndef TS_POOL_H
#define TS_POOL_H

typedef struct ts_pool ts_pool;
typedef void ts_pool_fn(void *arg, int worker, int nworkers);

/* nthreads >= 1 (1 = run inline). Returns 0 or a negative TS_E* code. */
int ts_pool_create(ts_pool **pool, int nthreads);
int ts_pool_size(const ts_pool *pool);
/* Runs fn(arg, w, n) for every worker w in [0, n) and returns when all are
 * done. Callers on several threads take turns, each run on all the pool's
 * threads (concurrent jobs scanning on the coordinator's pool, a tiled
 * scene's tiles on one machine's); fn must not run the pool again. */
void ts_pool_run(ts_pool *pool, ts_pool_fn *fn, void *arg);
void ts_pool_destroy(ts_pool *pool);

#endif
