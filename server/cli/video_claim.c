/* video_claim.c - whether a `texsyn video` work directory (--write-guides
 * DIR) holds frames of this very job, so that a rerun goes on where the
 * last one stopped (video_chain.h).
 *
 * The directory's "manifest" holds one line: a 64-bit FNV-1a hash of
 * everything the chains' bytes depend on: the stylize job's spec (every
 * parameter, the guides' weights, the seed), the frames, the keys' frame
 * numbers and the bytes of every key, input, pass, mask and given flow
 * frame (a movie's: as decoded), and the flow's maker. Where the server, the threads or -o differ, the frames are
 * the same (the bytes never depend on them), so they stay out. A frame of
 * other settings would be a wrong frame, silently: on any difference the
 * directory's chain files go and the chains start afresh, which says so. */
#include <dirent.h>
#include <errno.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "error.h"
#include "flow.h"
#include "util.h"
#include "video_chain.h"

#define MANIFEST_FORMAT "texsyn video work 1"

static uint64_t fnv(uint64_t h, const void *data, size_t n) {
  const uint8_t *p = data;
  for (size_t i = 0; i < n; i++) h = (h ^ p[i]) * 0x100000001b3ull;
  return h;
}

static uint64_t fnv_str(uint64_t h, const char *s) { return fnv(h, s, strlen(s) + 1); }

static int fnv_file(uint64_t *h, const char *path, char *err) {
  uint8_t *buf = NULL;
  size_t len = 0;
  int rc = ts_file_read(path, 1ull << 32, &buf, &len, err);
  if (rc == 0) *h = fnv(fnv(*h, &len, sizeof(len)), buf, len);
  free(buf);
  return rc;
}

/* The frames of a sequence; a frame that is not there (a flow has none
 * at one end) counts as absent. */
static int fnv_sequence(uint64_t *h, const ts_video *v, const char *pattern, char *err) {
  char path[TS_VIDEO_PATH];
  int rc = 0;
  for (long f = v->fr.first; rc == 0 && f <= v->fr.last; f++) {
    ts_frame_path(pattern, f, path, sizeof(path)); /* fits: checked */
    if (access(path, F_OK) == 0) rc = fnv_file(h, path, err);
    else *h = fnv_str(*h, "absent");
  }
  return rc;
}

int ts_video_hash(const ts_video *v, uint64_t *out, char *err) {
  char spec[TS_SPEC_MAX], line[256];
  int n = ts_jobspec_format(&v->job.spec, spec, sizeof(spec));
  if (n < 0) return ts_error(err, TS_ETOOBIG, "job spec too long");
  uint64_t h = fnv_str(0xcbf29ce484222325ull, MANIFEST_FORMAT);
  h = fnv_str(fnv_str(h, spec), ts_flow_method());
  snprintf(line, sizeof(line), "%ld %ld %d %d %d %d %.17g %.17g %.17g %.17g %.17g", v->fr.first, v->fr.last, v->w,
           v->h, v->channels, v->npass, v->input_weight, v->wt.edge, v->wt.position, v->wt.temporal, v->wt.mask);
  h = fnv_str(h, line);
  int rc = fnv_sequence(&h, v, v->input, err);
  const char *more[3] = {v->mask, v->flow, v->flow_back};
  for (int k = 0; rc == 0 && k < 3; k++) {
    h = fnv_str(h, more[k] != NULL ? "given" : "none");
    if (more[k] != NULL) rc = fnv_sequence(&h, v, more[k], err);
  }
  for (int p = 0; rc == 0 && p < v->npass; p++) {
    snprintf(line, sizeof(line), "pass %.17g", v->pass_weight[p]);
    h = fnv_str(h, line);
    rc = fnv_sequence(&h, v, v->pass[p], err);
  }
  for (int k = 0; rc == 0 && k < v->nkeys; k++) {
    snprintf(line, sizeof(line), "key %ld", v->key[k].frame);
    h = fnv_str(h, line);
    rc = fnv_file(&h, v->key[k].image, err);
  }
  *out = h;
  return rc;
}

/* The chains' files of dir ("from_*") removed; how many there were. */
static int forget_frames(const char *dir) {
  DIR *d = opendir(dir);
  struct dirent *e;
  char path[TS_VIDEO_PATH + 256];
  int n = 0;
  while (d != NULL && (e = readdir(d)) != NULL) {
    if (strncmp(e->d_name, "from_", 5) != 0) continue;
    snprintf(path, sizeof(path), "%s/%s", dir, e->d_name);
    n += unlink(path) == 0;
  }
  if (d != NULL) closedir(d);
  return n;
}

int ts_video_claim(const ts_video *v, const char *dir, uint64_t h, int *resume, char *err) {
  char path[TS_VIDEO_PATH + 16], want[64];
  *resume = 0;
  snprintf(want, sizeof(want), "%s %016" PRIx64 "\n", MANIFEST_FORMAT, h);
  snprintf(path, sizeof(path), "%s/manifest", dir);
  uint8_t *buf = NULL;
  size_t len = 0;
  char why[TS_ERR_LEN];
  if (ts_file_read(path, 4096, &buf, &len, why) == 0 && len == strlen(want) && memcmp(buf, want, len) == 0)
    *resume = 1;
  free(buf);
  if (!*resume && forget_frames(dir) > 0 && !v->job.quiet)
    fprintf(stderr, "texsyn video: %s held frames of other settings, inputs or keys (its manifest differs); they "
            "were removed and the chains start afresh\n", dir);
  return *resume ? 0 : ts_file_write(path, want, strlen(want), err);
}
