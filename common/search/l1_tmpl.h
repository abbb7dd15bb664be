/* l1_tmpl.h - the SIMD L1 scan, written once and instantiated by l1_x86.c
 * for each instruction set (SSE2, AVX2, AVX-512BW). No include guard: it is
 * included once per variant with these macros defined, and #undefs them:
 *
 *   TS_K(name)     variant-specific function name
 *   TS_TARGET      __attribute__((target(...))) enabling the instruction set
 *   TS_V, TS_VB    vector type and its size in bytes (16, 32 or 64)
 *   TS_QMAX        most queries per pass (1..6), bounded by the registers
 *   TS_LOAD(p) TS_STORE(p, v) TS_BCAST(u64) TS_ZERO() TS_ADD(a, b)
 *   TS_CHUNK(p)    the 8 bytes at p in every 64-bit lane
 *   TS_ANDCHUNK(v, p)  v AND the 8 bytes at p in every lane
 *   TS_SAD(a, b)   per 64-bit lane: sum of |a - b| over its 8 bytes
 *   TS_MULW(a, w)  per 64-bit lane: low 32 bits of a times low 32 bits of w
 *   TS_UPDATE(best, grp, d, gv)  lanes where d < best take d and gv
 *
 * How it works. One register holds TS_VB / 8 lanes of a group chunk, so a
 * group chunk is TS_NSUB registers ("sub-vectors"), scanned one after the
 * other. A pass takes one block of groups (TS_L1_BLOCK_BYTES) and up to
 * TS_QMAX queries, and for every group and chunk does one aligned load of the
 * reference chunk and, per query, one psadbw against the query chunk
 * broadcast straight from memory: no horizontal work, no shuffles, and any
 * vector length without tiling. Several queries share each loaded chunk
 * because on the Zen 5 this was tuned on 64-byte loads sustain only ~0.7 per
 * cycle (~45 B/cycle from L1) while psadbw issues twice per cycle and the
 * 8-byte broadcast loads go at 2 per cycle beside it: with one query the
 * scan is load-bound, with six (AVX-512) it is bound by psadbw and its adds.
 * Measured on 7-chunk vectors: 4 queries 68, 6 queries 74 B/cycle; keeping
 * the query chunks in registers instead (tiling long vectors) was no faster
 * and far more code.
 *
 * Weighted parts (l1.h): each part's chunks are summed in one accumulator
 * per query and multiplied by the part's weight once, with one vpmuludq (a
 * part's sum is below 2^20 and its weight below 2^32, so the 32x32->64-bit
 * multiply is exact): per part and query one multiply and one add, however
 * long the part. The first two parts, all the MRF has, are the straight
 * path, with both weights in registers, so the MRF's scan does the work of
 * a fixed fine/coarse kernel. Further parts (MANY, instances of their own)
 * loop, broadcasting their weight from memory once per group, shared by the
 * pass's queries.
 *
 * A per-lane running minimum, with the group number where it was first
 * reached, keeps the tie rule: groups arrive in increasing order and only
 * strictly smaller distances replace. Masked queries arrive already ANDed
 * with their masks (l1_x86.c), and each reference chunk is ANDed with the
 * query's mask chunk before the psadbw. */

#define TS_L (TS_VB / 8)     /* lanes (reference vectors) per register */
#define TS_NSUB (64 / TS_VB) /* registers per group chunk */

/* Statement M(i) for every query i of the pass (Q is a constant). */
#define TS_EACH(M) \
  M(0) if (Q > 1) M(1) if (Q > 2) M(2) if (Q > 3) M(3) if (Q > 4) M(4) if (Q > 5) M(5)
#define TS_EACH_ACC(M, a)                                                                    \
  M(a, 0) if (Q > 1) M(a, 1) if (Q > 2) M(a, 2) if (Q > 3) M(a, 3) if (Q > 4) M(a, 4) if (Q > 5) \
      M(a, 5)

/* Chunk k of the reference against query i, seen through its mask. */
#define TS_SAD_CHUNK(i, k)                                                    \
  TS_SAD(MSK ? TS_ANDCHUNK(rv_, p->m[i] + (size_t)(k) * TS_L1_CHUNK) : rv_, \
         TS_CHUNK(p->q[i] + (size_t)(k) * TS_L1_CHUNK))
#define TS_SAD_FIRST(a, i) a##i = TS_SAD_CHUNK(i, k);
#define TS_SAD_NEXT(a, i) a##i = TS_ADD(a##i, TS_SAD_CHUNK(i, k));

/* a0.. = SAD of chunks [k0, k1) for each query, k0 < k1 (parts are never
 * empty). The first chunk initialises, so no add is spent on zeros. */
#define TS_ACCUMULATE(a, k0, k1)                   \
  do {                                             \
    uint32_t k = (k0);                             \
    TS_V rv_ = TS_LOAD(r + (size_t)k * 64);        \
    TS_EACH_ACC(TS_SAD_FIRST, a)                   \
    for (k++; k < (k1); k++) {                     \
      rv_ = TS_LOAD(r + (size_t)k * 64);           \
      TS_EACH_ACC(TS_SAD_NEXT, a)                  \
    }                                              \
  } while (0)

/* Weighting: the first two parts' sums a0.. and c0.. start the distances
 * d0.. (with one part, c0.. and w1 are zero), and any further part's sums
 * a0.. add to them with weight w. */
#define TS_WEIGH_TWO(i) d##i = TS_ADD(TS_MULW(a##i, w0), TS_MULW(c##i, w1));
#define TS_WEIGH_NEXT(i) d##i = TS_ADD(d##i, TS_MULW(a##i, w));

#define TS_STATE_LOAD(i)             \
  {                                  \
    b##i = TS_LOAD(p->dist[i]);      \
    x##i = TS_LOAD(p->grp[i]);       \
  }
#define TS_STATE_STORE(i)            \
  {                                  \
    TS_STORE(p->dist[i], b##i);      \
    TS_STORE(p->grp[i], x##i);       \
  }
#define TS_FOLD(i)                                                    \
  {                                                                   \
    if (PEN) d##i = TS_ADD(d##i, pen);                                \
    TS_UPDATE(b##i, x##i, d##i, gv);                                  \
  }

/* One pass: groups [ga, ga + ngr) of one sub-vector against Q queries. Q,
 * MSK (masked), PEN (penalties) and MANY (more than two parts) are
 * constants at every call site. MANY has instances of its own because the
 * loop over further parts, even never entered, changed the register
 * allocation of the one- and two-part kernels, the MRF's: up to 4% slower
 * batches and 10% slower single scans on a Xeon (Emerald Rapids). */
static inline __attribute__((always_inline)) TS_TARGET void TS_K(pass)(
    const ts__l1_pass *p, const uint32_t Q, const int MSK, const int PEN, const int MANY) {
  const uint32_t nt = p->nchunks, np = p->nparts;
  const uint32_t *end = p->part_end;
  const uint64_t *weight = p->weight;
  const uint32_t e0 = end[0], e1 = np > 1 ? end[1] : 0;
  const TS_V one = TS_BCAST(1), w0 = TS_BCAST(weight[0]);
  const TS_V w1 = np > 1 ? TS_BCAST(weight[1]) : TS_ZERO();
  TS_V gv = TS_BCAST(p->ga);
  TS_V b0, x0, b1 = TS_ZERO(), x1 = TS_ZERO(), b2 = TS_ZERO(), x2 = TS_ZERO(), b3 = TS_ZERO(),
              x3 = TS_ZERO(), b4 = TS_ZERO(), x4 = TS_ZERO(), b5 = TS_ZERO(), x5 = TS_ZERO();
  TS_EACH(TS_STATE_LOAD)
  const uint8_t *r = p->ref;
  for (uint32_t j = 0; j < p->ngr; j++, r += p->gstride, gv = TS_ADD(gv, one)) {
    /* A few lines per group keep the prefetches spread over the pass. A
     * lone query on whole-chunk registers never prefetches (see
     * pass_prefetch), so that kernel, the tightest loop, skips the test. */
    if ((Q > 1 || TS_NSUB > 1) && j < p->pfn)
      for (uint32_t k = 0; k < nt; k++) _mm_prefetch(p->pf + j * p->gstride + k * 64, _MM_HINT_T0);
    TS_V a0 = TS_ZERO(), a1 = TS_ZERO(), a2 = TS_ZERO(), a3 = TS_ZERO(), a4 = TS_ZERO(),
         a5 = TS_ZERO();
    TS_V c0 = TS_ZERO(), c1 = TS_ZERO(), c2 = TS_ZERO(), c3 = TS_ZERO(), c4 = TS_ZERO(),
         c5 = TS_ZERO();
    TS_V d0, d1, d2, d3, d4, d5;
    TS_ACCUMULATE(a, 0, e0);
    /* Expected: laid out of line, the second part cost two taken jumps
     * per group, ~5% of a single-query scan. */
    if (__builtin_expect(np > 1, 1)) TS_ACCUMULATE(c, e0, e1);
    TS_EACH(TS_WEIGH_TWO)
    for (uint32_t g = 2; MANY && g < np; g++) {
      TS_ACCUMULATE(a, end[g - 1], end[g]);
      const TS_V w = TS_BCAST(weight[g]);
      TS_EACH(TS_WEIGH_NEXT)
    }
    TS_V pen = PEN ? TS_LOAD(p->pen + (size_t)j * TS_L1_GROUP) : TS_ZERO();
    TS_EACH(TS_FOLD)
  }
  TS_EACH(TS_STATE_STORE)
}

/* The instances, indexed [queries - 1][masked][penalty][more than two parts]. */
#define TS_INST(name, Q, MSK, PEN, MANY) \
  static TS_TARGET void TS_K(name)(const ts__l1_pass *p) { TS_K(pass)(p, Q, MSK, PEN, MANY); }
#define TS_INST2(n, Q, MSK, PEN) \
  TS_INST(n, Q, MSK, PEN, 0)     \
  TS_INST(n##_many, Q, MSK, PEN, 1)
#define TS_INST8(n, Q)          \
  TS_INST2(n, Q, 0, 0)          \
  TS_INST2(n##_pen, Q, 0, 1)    \
  TS_INST2(n##_msk, Q, 1, 0)    \
  TS_INST2(n##_msk_pen, Q, 1, 1)
#define TS_PAIR(n) {TS_K(n), TS_K(n##_many)}
#define TS_ROW(n) \
  {{TS_PAIR(n), TS_PAIR(n##_pen)}, {TS_PAIR(n##_msk), TS_PAIR(n##_msk_pen)}}
TS_INST8(q1, 1)
#if TS_QMAX >= 2
TS_INST8(q2, 2)
#endif
#if TS_QMAX >= 3
TS_INST8(q3, 3)
#endif
#if TS_QMAX >= 4
TS_INST8(q4, 4)
#endif
#if TS_QMAX >= 5
TS_INST8(q5, 5)
#endif
#if TS_QMAX >= 6
TS_INST8(q6, 6)
#endif
static ts__l1_pass_fn *const TS_K(passes)[TS_QMAX][2][2][2] = {
    TS_ROW(q1),
#if TS_QMAX >= 2
    TS_ROW(q2),
#endif
#if TS_QMAX >= 3
    TS_ROW(q3),
#endif
#if TS_QMAX >= 4
    TS_ROW(q4),
#endif
#if TS_QMAX >= 5
    TS_ROW(q5),
#endif
#if TS_QMAX >= 6
    TS_ROW(q6),
#endif
};

/* Groups [ga, gb) against queries [0, nq) of the current slice. */
static TS_TARGET void TS_K(range)(ts__l1_scan *sc, uint32_t ga, uint32_t gb, uint32_t g1,
                                  const uint64_t *pen, uint32_t nq, uint32_t qmax) {
  const ts_l1_set *set = sc->set;
  ts__l1_pass p;
  pass_init(&p, sc, ga, gb);
  pass_prefetch(&p, sc, g1, (int)(TS_NSUB * ((nq + qmax - 1) / qmax)));
  for (uint32_t s = 0; s < TS_NSUB; s++) {
    p.ref = set->data + (size_t)ga * p.gstride + s * TS_VB;
    p.pen = pen != NULL ? pen + s * TS_L : NULL;
    for (uint32_t q = 0; q < nq; q += qmax) {
      uint32_t n = nq - q < qmax ? nq - q : qmax;
      for (uint32_t i = 0; i < n; i++) {
        p.dist[i] = sc->lanes[q + i].dist + s * TS_L;
        p.grp[i] = sc->lanes[q + i].grp + s * TS_L;
        p.q[i] = sc->queries + (size_t)(q + i) * p.vbytes;
        p.m[i] = sc->masks != NULL ? sc->masks + (size_t)(q + i) * p.vbytes : NULL;
      }
      TS_K(passes)[n - 1][sc->masks != NULL][pen != NULL][p.nparts > 2](&p);
      p.pfn = 0; /* the first pass has brought the block in */
    }
  }
}

/* qmax: queries per pass, TS_QMAX for batches and 1 for `single`. */
static TS_TARGET void TS_K(scan)(const ts_l1_set *set, uint32_t g0, uint32_t g1,
                                 const uint8_t *queries, const uint8_t *masks,
                                 const uint32_t *penalty, uint32_t nq, ts_l1_best *best,
                                 uint32_t qmax) {
  if (g1 > set->ngroups) g1 = set->ngroups;
  if (g0 >= g1 || nq == 0) return;
  ts__l1_scan sc;
  scan_init(&sc, set, masks);
  for (uint32_t qa = 0; qa < nq; qa += sc.slice) {
    uint32_t qn = nq - qa < sc.slice ? nq - qa : sc.slice;
    scan_slice(&sc, queries, masks, qa, qn);
    for (uint32_t b0 = g0, b1; b0 < g1; b0 = b1) {
      b1 = g1 - b0 < sc.block ? g1 : b0 + sc.block;
      uint32_t full = block_pen(&sc, b0, b1, penalty);
      if (full > b0) TS_K(range)(&sc, b0, full, g1, penalty != NULL ? sc.pen : NULL, qn, qmax);
      if (full < b1)
        TS_K(range)(&sc, full, b1, g1, sc.pen + (size_t)(full - b0) * TS_L1_GROUP, qn, qmax);
    }
    ts__l1_lanes_reduce(sc.lanes, qn, best + qa);
  }
}

void TS_K(single)(const ts_l1_set *set, uint32_t g0, uint32_t g1, const uint8_t *queries,
                  const uint8_t *masks, const uint32_t *penalty, uint32_t nq, ts_l1_best *best) {
  size_t vbytes = (size_t)set->nchunks * TS_L1_CHUNK;
  for (uint32_t q = 0; q < nq; q++)
    TS_K(scan)(set, g0, g1, queries + q * vbytes, masks != NULL ? masks + q * vbytes : NULL,
               penalty, 1, best + q, 1);
}

void TS_K(batch)(const ts_l1_set *set, uint32_t g0, uint32_t g1, const uint8_t *queries,
                 const uint8_t *masks, const uint32_t *penalty, uint32_t nq, ts_l1_best *best) {
  TS_K(scan)(set, g0, g1, queries, masks, penalty, nq, best, TS_QMAX);
}

#undef TS_L
#undef TS_NSUB
#undef TS_EACH
#undef TS_EACH_ACC
#undef TS_SAD_CHUNK
#undef TS_SAD_FIRST
#undef TS_SAD_NEXT
#undef TS_ACCUMULATE
#undef TS_STATE_LOAD
#undef TS_STATE_STORE
#undef TS_FOLD
#undef TS_WEIGH_TWO
#undef TS_WEIGH_NEXT
#undef TS_INST
#undef TS_INST2
#undef TS_INST8
#undef TS_PAIR
#undef TS_ROW
/* The parameters too, ready for the next variant. */
#undef TS_K
#undef TS_TARGET
#undef TS_V
#undef TS_VB
#undef TS_QMAX
#undef TS_LOAD
#undef TS_STORE
#undef TS_BCAST
#undef TS_ZERO
#undef TS_ADD
#undef TS_CHUNK
#undef TS_ANDCHUNK
#undef TS_SAD
#undef TS_MULW
#undef TS_UPDATE
