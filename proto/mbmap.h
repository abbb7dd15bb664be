/* mbmap.h - the Modbus register maps of texsyn-worker and texsyn-server
 * (README, "Monitoring over Modbus", has the same table for users).
 *
 * Input registers (function 04), 16-bit each; u32 values take 2 registers
 * and u64 values 4, most significant word first. Both daemons share the
 * block 0..31; the coordinator adds 32..47, a worker 32..37. Coils (functions 01, 05, 15)
 * switch the daemon; writes need --modbus-control. */
#ifndef TS_MBMAP_H
#define TS_MBMAP_H

#define TS_MB_MAGIC 0x5453 /* "TS" */
#define TS_MB_BUILD 5      /* bumped with every release of the map's meaning */
#define TS_MB_UNKNOWN 0xFFFF

enum {
  TS_MB_IR_MAGIC = 0,      /* 0x5453 */
  TS_MB_IR_PROTOCOL = 1,   /* wire protocol version (PROTOCOL.md) */
  TS_MB_IR_BUILD = 2,      /* TS_MB_BUILD */
  TS_MB_IR_ROLE = 3,       /* 1 coordinator, 2 worker */
  TS_MB_IR_STATE = 4,      /* ts_mb_state */
  TS_MB_IR_THREADS = 5,    /* scan threads */
  TS_MB_IR_SIMD = 6,       /* 0 scalar, 1 mmx, 2 sse2, 3 avx2, 4 avx512 */
  TS_MB_IR_CPU_SHARE = 7,  /* per mille of the time its threads wanted a CPU that they
                              had one (others waited in the run queue), over the last
                              ~second; TS_MB_UNKNOWN when they hardly ran */
  TS_MB_IR_UPTIME = 8,     /* u32 seconds since start */
  TS_MB_IR_ERRORS = 10,    /* u32 protocol errors and failed requests */
  TS_MB_IR_RATE = 12,      /* u64 calibrated scan rate, bytes of vectors/s */
  TS_MB_IR_VECTORS = 16,   /* u64 reference vectors held in slices */
  TS_MB_IR_BATCHES = 20,   /* u64 query batches answered */
  TS_MB_IR_QUERIES = 24,   /* u64 queries answered */
  TS_MB_IR_SCAN_RATE = 28, /* u64 scan rate of the recent batches (1 s average), bytes/s */
  TS_MB_IR_COMMON_END = 32,
  /* coordinator only */
  TS_MB_IR_WORKERS = 32,   /* workers ready */
  TS_MB_IR_QUEUED = 33,    /* jobs queued */
  TS_MB_IR_RUNNING = 34,   /* jobs running */
  TS_MB_IR_DONE = 35,      /* u32 jobs done */
  TS_MB_IR_FAILED = 37,    /* u32 jobs failed */
  TS_MB_IR_JOB = 39,       /* u64 id of the running job that started first, else
                              of the job that ended last (0: none) */
  TS_MB_IR_PROGRESS = 43,  /* that job's progress, per mille */
  TS_MB_IR_LEVEL = 44,     /* the level it synthesises, machine-numbered: L-1 the coarsest down to
                            * 0 the finest (texsyn status shows "level L-this of L") */
  TS_MB_IR_ETA = 45,       /* u32 its ETA in seconds (0xFFFFFFFF: unknown) */
  TS_MB_IR_PAUSED = 47,    /* 1 while the queue is paused */
  TS_MB_IR_SERVER_END = 48,
  /* worker only */
  TS_MB_IR_SOURCES_LOADED = 32, /* u32 PatchMatch sources loaded ('G') since start */
  TS_MB_IR_SOURCES_HELD = 34,   /* PatchMatch sources held now */
  TS_MB_IR_PASSES = 35,         /* u32 PatchMatch passes answered ('T') */
  TS_MB_IR_WORKER_END = 37,
};

typedef enum {
  TS_MB_IDLE = 0,     /* holds no slice */
  TS_MB_LOADING = 1,  /* building a slice's vectors */
  TS_MB_SCANNING = 2, /* holds slices (answering batches) */
  TS_MB_DRAINING = 3, /* drain coil set: gets no new slices */
  TS_MB_FAILED = 4,
} ts_mb_state;

enum {
  TS_MB_COIL_DRAIN = 0, /* worker: 1 = drain */
  TS_MB_COIL_PAUSE = 0, /* coordinator: 1 = queue paused, 0 = running */
};

#endif
