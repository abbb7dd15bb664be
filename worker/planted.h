/* planted.h - debug-only faults planted in a worker on purpose, so the
 * integration suite can prove that it notices a daemon's memory errors
 * (tests/integration/test_daemon_checks.py): a test whose worker printed a
 * sanitizer report must fail even when everything it asserts holds.
 *
 * TEXSYN_PLANT_FAULT names the fault, done at the worker's first query:
 *   overflow   reads a byte past a heap block (AddressSanitizer)
 *   leak       loses a heap block (LeakSanitizer, at exit)
 *   undefined  shifts a 32-bit value by 32 (UBSan)
 * Only sanitizer builds (make SAN=1, which defines TEXSYN_FAULT_HOOKS)
 * have them; elsewhere ts_planted_fault compiles to nothing. */
#ifndef TS_PLANTED_H
#define TS_PLANTED_H

#ifdef TEXSYN_FAULT_HOOKS
void ts_planted_fault(void);
#else
static inline void ts_planted_fault(void) {}
#endif

#endif
