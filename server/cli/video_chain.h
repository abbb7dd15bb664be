/* video_chain.h - the chains of stylize jobs of `texsyn video` (video.c).
 *
 * A chain starts at a key K and walks one frame at a time, forward or
 * backward, to its last frame. Every frame t of it is one stylize job
 * whose exemplar is the key's painting and whose guide pairs are
 *   colour     input frame K        / input frame t
 *   edges      edges of frame K     / edges of frame t       (weight > 0)
 *   position   the key's own x, y   / the key's x, y carried from K to t
 *                                     along the flow          (weight > 0)
 *   temporal   the key's painting   / the chain's frame t-1 (or t+1)
 *                                     warped onto t           (weight > 0)
 *              and 255 - each         (half the weight each, 0 where occluded:
 *                                     ts_guide_temporal_pair)
 *   mask       the mask at frame K  / the mask at frame t    (--mask, weight > 0)
 *   --pass P   P at frame K         / P at frame t
 * (Jamriška et al. 2019, built from video_guides.h and flow.h; the flow
 * computed, or given with --flow: video_flow.h). The source
 * side is the same for the whole chain, so on a coordinator the workers
 * keep the exemplar's sources from one frame to the next, as for
 * `stylize --frames` (frames.h).
 *
 * Where the flow check finds a pixel occluded (its content is not in the
 * previous frame) the positional guide restarts at the pixel's own place
 * (video_guides.h) and the temporal guide is weighted out there, as in
 * the paper: its pair adds the same to every candidate, so the previous
 * frame warped from elsewhere cannot vote for whatever occluded it. The
 * error map keeps that constant (255 per channel at half the temporal
 * weight, per occluded pixel of the patch): a chain that had to invent
 * the content there piles up more error, and the blend trusts it less.
 *
 * Every guide is written as an 8-bit PNG to a work directory and the job
 * reads it back, embedded or on a coordinator alike: the same bytes go in
 * either way. The chains advance in rounds: each round takes one frame of
 * every chain not yet at its end, so on a coordinator the chains' jobs run
 * side by side while each chain stays in order. */
#ifndef TS_VIDEO_CHAIN_H
#define TS_VIDEO_CHAIN_H

#include "frames.h"
#include "jobcmd.h"
#include "stylit.h"
#include "video_guides.h"

#define TS_VIDEO_MAX_KEYS 64
/* Guides beyond the colour, edge, two position and two temporal ones
 * (and the mask's, with --mask). */
#define TS_VIDEO_MAX_PASSES (TS_STYLIT_MAX_GUIDES - 6)
#define TS_VIDEO_PATH 4096

typedef struct {
  long frame;
  const char *image; /* the painted key, the frames' size */
} ts_video_key;

typedef struct {
  ts_job_cmd job; /* the stylize engine's parameters and where jobs run */
  const char *input, *out, *guides_dir;
  const char *mask; /* --mask PATTERN or NULL (video_mask.h) */
  const char *flow, *flow_back; /* --flow, --flow-back PATTERN or NULL (video_flow.h) */
  ts_frames fr;
  int nkeys; /* sorted by frame, distinct */
  ts_video_key key[TS_VIDEO_MAX_KEYS];
  int npass;
  const char *pass[TS_VIDEO_MAX_PASSES];
  double input_weight, pass_weight[TS_VIDEO_MAX_PASSES];
  ts_video_weights wt; /* the made guides' (video_guides.h) */
  int w, h, channels; /* the frames' size, the keys' channels (checked) */
  /* On a coordinator, what every job says of the sequence it is a frame
   * of (jobspec.h; its chain and frame set per job), for the operations
   * page; id "" in-process. */
  ts_jobspec_seq seq;
} ts_video;

/* The work directory's file for key `key` and frame t: what ("out.png",
 * "temporal.png", "report.json", ...) of the chain from that key. */
void ts_video_chain_file(const char *dir, long key, long t, const char *what, char *out, size_t cap);

/* An image of the frames' size and the keys' channels as interleaved
 * 8-bit samples (stylize's conversion), into px. */
int ts_video_read8(const ts_video *v, const char *path, uint8_t *px, char *err);

/* Sets the stylize job's guide count and weights from v's weights. */
int ts_video_weigh(ts_video *v, char *err);

/* Writes each key's 8-bit painting and source guides to dir, then checks
 * the stylize job of a key's own frame with the engine (sizes, levels
 * against the patch): 0, TS_EINVAL (nothing stylized yet) or an error. */
int ts_video_prepare(const ts_video *v, const char *dir, char *err);

/* Runs every chain (ts_video_prepare first): the stylized frames are the
 * "out.png" files of dir (a key's own frame: its painting), each with its
 * "error.tif" (the stylize job's error map), "acc.raw" (the error piled
 * up along the chain, w*h floats), "flow.raw" (the flow from it to the
 * chain's frame before, 2*w*h floats) and "pos.raw" (its position guide).
 * resume: dir holds this job's frames from an earlier run (ts_video_claim):
 * each chain goes on after its last finished frame. On a coordinator, a
 * lost connection is made again (for up to two minutes) and the chains
 * follow their jobs on the restarted coordinator. Prints per frame the
 * chain and the frame unless quiet. 0 or an error with its message. */
int ts_video_run_chains(const ts_video *v, const char *dir, int resume, char *err);

/* The stylize jobs the chains take: every chain's frames but its key's. */
uint32_t ts_video_job_count(const ts_video *v);

/* A 64-bit hash of everything the chains' bytes depend on (video_claim.c):
 * 0 or an error reading an input. */
int ts_video_hash(const ts_video *v, uint64_t *hash, char *err);

/* Whether the work directory holds this job's frames from an earlier run
 * (its manifest, holding hash, ts_video_hash): *resume = 1; else its chain
 * files are removed (saying so when there were some) and the manifest
 * written for this job. 0 or an error. */
int ts_video_claim(const ts_video *v, const char *dir, uint64_t hash, int *resume, char *err);

/* Raw native floats, n of them: a whole file (written by rename), or
 * TS_EFORMAT when it holds another count. */
int ts_video_write_floats(const char *path, const float *f, size_t n, char *err);
int ts_video_read_floats(const char *path, float *f, size_t n, char *err);

#endif
