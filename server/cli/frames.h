/* frames.h - a job over a sequence of frames (`--frames A..B`).
 *
 * Input and output paths may hold a frame-number pattern, as printf writes
 * an int: %d, or %0Nd for N digits with leading zeros (%% is a per cent
 * sign); a path with one names a file per frame, a path without one the
 * same file for every frame. Every output needs one (the frames would
 * overwrite each other); inputs the command calls fixed (stylize: the
 * exemplar and the source guides) may not have one.
 *
 * Before any frame runs, every frame's inputs must be readable and its
 * outputs writable, so a missing frame costs no work. Then:
 *   embedded      the frames run one after another in this process, on
 *                 one search backend, each with all the threads; the
 *                 inputs without a pattern are read once;
 *   coordinator   every frame is a job of its own, all submitted at once
 *                 (the coordinator runs `--jobs` of them side by side) and
 *                 fetched in order; the workers keep the exemplar's
 *                 PatchMatch sources from one frame to the next
 *                 (server/pool/search_field.c), so they are sent once.
 * Either way a frame's bytes are those of the single job on its files. */
#ifndef TS_FRAMES_H
#define TS_FRAMES_H

#include <stddef.h>

#include "jobcmd.h"

#define TS_FRAMES_MAX 10000  /* frames in one sequence */
#define TS_FRAME_LAST 999999 /* the highest frame number */

typedef struct {
  long first, last;
} ts_frames;

/* "A..B", 0 <= A <= B <= TS_FRAME_LAST, at most TS_FRAMES_MAX frames: 0,
 * or TS_EINVAL with a message. */
int ts_frames_parse(const char *s, ts_frames *f, char *err);
/* The frame-number conversions in path (0 or more), or TS_EINVAL with a
 * message when a '%' starts anything else. */
int ts_frame_pattern(const char *path, char *err);
/* The pattern with the frame number put in (a path without a pattern is
 * copied): 0, or TS_ETOOBIG when it does not fit cap bytes. */
int ts_frame_path(const char *pattern, long frame, char *out, size_t cap);

/* Runs o once per frame (o's paths the patterns); fixed[k], when not
 * NULL, names input k for the message that it may not vary. The exit
 * status, as ts_job_run's. */
int ts_job_run_frames(const ts_job_cmd *o, const ts_frames *f, const char *const *fixed);

#endif
