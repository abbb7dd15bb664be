/* jobs_spool.c - the job queue's spool on disk (jobs_spool.h): a job's
 * files written and removed, the spool reloaded at start (judged by
 * spool.h), SPOOL/last-id and SPOOL/lock. Every file is written by
 * ts_file_write (util.h), atomically and durably. */
#include "jobs_spool.h"

#include <dirent.h>
#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <time.h>
#include <unistd.h>

#include "error.h"
#include "jobs_queue.h"
#include "spool.h"
#include "util.h"

/* Makes directory dir, durably: once this returns, its parent's entry for
 * it survives a power loss. */
static int make_dir(const char *dir, char *err) {
  /* Owner only: jobs are users' images (the daemon's umask is 077 too). */
  if (mkdir(dir, 0700) != 0) return ts_error(err, TS_EIO, "cannot create %s: %s", dir, strerror(errno));
  if (ts_parent_sync(dir) != 0)
    return ts_error(err, TS_EIO, "cannot create %s: syncing its parent: %s", dir, strerror(errno));
  return 0;
}

/* Reads a small file of the spool for spool.h's judges: its bytes into
 * *buf (the caller frees it), or why it could not (f->why, pointing into
 * why, stays NULL when the file is missing). */
static void read_spool_file(const char *path, size_t cap, ts_spool_file *f, uint8_t **buf, char why[TS_ERR_LEN]) {
  size_t len;
  *f = (ts_spool_file){NULL, 0, NULL};
  if (ts_file_read(path, cap, buf, &len, why) == 0) {
    f->data = (const char *)*buf;
    f->len = len;
    return;
  }
  struct stat st;
  if (lstat(path, &st) == 0 || errno != ENOENT) f->why = why;
}

void jobs_file_path(const job *jb, const char *name, char *out, size_t cap) {
  snprintf(out, cap, "%s/%s", jb->dir, name);
}

/* Bytes of the files in a job's directory (it holds no subdirectories). */
static uint64_t dir_bytes(const char *dir) {
  DIR *d = opendir(dir);
  if (d == NULL) return 0;
  uint64_t total = 0;
  struct dirent *e;
  struct stat st;
  while ((e = readdir(d)) != NULL)
    if (fstatat(dirfd(d), e->d_name, &st, AT_SYMLINK_NOFOLLOW) == 0 && S_ISREG(st.st_mode))
      total += (uint64_t)st.st_size;
  closedir(d);
  return total;
}

/* Whether a file name is a temporary one of util.h's atomic writes
 * ("NAME.tmp-PID"; "NAME.tmp" in a spool of an older coordinator) or of
 * the image library ("NAME.tmp-PID-N"). */
static int temporary_name(const char *name) {
  const char *t = strstr(name, ".tmp");
  return t != NULL && (t[4] == '\0' || t[4] == '-');
}

/* Removes the temporary files a coordinator killed while writing left in
 * a job's directory, before the job runs again. */
void jobs_remove_temporaries(const char *dir) {
  DIR *d = opendir(dir);
  if (d == NULL) return;
  struct dirent *e;
  while ((e = readdir(d)) != NULL)
    if (temporary_name(e->d_name)) unlinkat(dirfd(d), e->d_name, 0);
  closedir(d);
}

/* Removes a job's directory and the files in it: 0, or -1 with errno
 * telling the first failure (the other files are removed all the same). */
int jobs_remove_dir(const char *dir) {
  DIR *d = opendir(dir);
  if (d == NULL) return errno == ENOENT ? 0 : -1;
  int first = 0;
  struct dirent *e;
  while ((e = readdir(d)) != NULL)
    if (strcmp(e->d_name, ".") != 0 && strcmp(e->d_name, "..") != 0 && unlinkat(dirfd(d), e->d_name, 0) != 0 &&
        first == 0)
      first = errno;
  closedir(d);
  if (rmdir(dir) != 0 && first == 0) first = errno;
  errno = first;
  return first != 0 ? -1 : 0;
}

/* A checkpoint left behind only takes room: the job is final. So do its
 * checkpoint pieces (a tiled scene's finished tiles). */
static void drop_job_checkpoint(ts_jobs *j, job *jb) {
  char path[JOBS_PATH + 32];
  jobs_file_path(jb, JOBS_CHECKPOINT, path, sizeof(path));
  if (unlink(path) != 0 && errno != ENOENT)
    jobs_log(j, "job %" PRIu64 ": cannot remove its checkpoint %s: %s; it stays until the job is deleted", jb->id,
             path, strerror(errno));
  DIR *d = opendir(jb->dir);
  if (d == NULL) return;
  struct dirent *e;
  while ((e = readdir(d)) != NULL)
    if (strncmp(e->d_name, JOBS_PIECE_PREFIX, strlen(JOBS_PIECE_PREFIX)) == 0 && unlinkat(dirfd(d), e->d_name, 0) != 0)
      jobs_log(j, "job %" PRIu64 ": cannot remove its checkpoint piece %s: %s; it stays until the job is deleted",
               jb->id, e->d_name, strerror(errno));
  closedir(d);
}

/* Records a final state on disk, then in memory. A "done" that cannot be
 * recorded is not told to clients: the job fails with the reason, and a
 * restart, finding no state, runs it again (the same bytes). */
void jobs_finish(ts_jobs *j, job *jb, int state, const char *text) {
  char path[JOBS_PATH + 16], buf[TS_ERR_LEN + 32], err[TS_ERR_LEN], why[TS_ERR_LEN];
  jobs_file_path(jb, "state", path, sizeof(path));
  int n = state == TS_JOB_DONE ? snprintf(buf, sizeof(buf), "done\n")
          : state == TS_JOB_CANCELED ? snprintf(buf, sizeof(buf), "canceled\n")
                                     : snprintf(buf, sizeof(buf), "failed: %s\n", text);
  if (ts_file_write(path, buf, (size_t)n, err) != 0) {
    jobs_log(j, "job %" PRIu64 ": %s", jb->id, err);
    if (state == TS_JOB_DONE) {
      snprintf(why, sizeof(why), "%.400s; its results are written: a restart of the coordinator brings it back", err);
      state = TS_JOB_FAILED;
      text = why;
    }
  }
  if (state == TS_JOB_DONE) jobs_log(j, "job %" PRIu64 " done in %.2fs", jb->id, ts_now() - jb->started);
  else jobs_log(j, "job %" PRIu64 " %s%s%s", jb->id, ts_job_state_name((uint8_t)state), text[0] ? ": " : "", text);
  drop_job_checkpoint(j, jb);
  uint64_t bytes = dir_bytes(jb->dir); /* the reserve becomes what was written */
  pthread_mutex_lock(&j->lock);
  j->spool_bytes = j->spool_bytes - jb->bytes + bytes;
  jb->bytes = bytes;
  client_share *cs = jobs_share_of(j, jb->client);
  if (cs && cs->unfinished > 0) cs->unfinished--;
  jb->st.state = (uint8_t)state;
  j->last_ended = jb->id;
  if (state == TS_JOB_DONE) jb->st.permille = 1000;
  jb->st.eta_ms = 0;
  jb->st.ended_ms = ts_clock_ms(); /* about the state file's time, which a restart reads */
  snprintf(jb->st.text, sizeof(jb->st.text), "%s", text);
  jobs_changed(j, jb);
  pthread_mutex_unlock(&j->lock);
}

#define JOBS_ATTEMPTS "attempts"

/* The runs counted in a job's directory (0: none, or unreadable). */
static unsigned attempts_of(const char *dir) {
  char path[JOBS_PATH + 16];
  uint8_t *buf = NULL;
  size_t len;
  snprintf(path, sizeof(path), "%s/%s", dir, JOBS_ATTEMPTS);
  if (ts_file_read(path, 32, &buf, &len, NULL) != 0) return 0;
  char text[33];
  memcpy(text, buf, len);
  text[len] = '\0';
  free(buf);
  int n;
  text[strcspn(text, "\n")] = '\0';
  return ts_parse_int(text, 0, 1000000, &n) == 0 ? (unsigned)n : 0;
}

void jobs_attempt_begin(ts_jobs *j, const job *jb) {
  char path[JOBS_PATH + 16], text[32], err[TS_ERR_LEN];
  jobs_file_path(jb, JOBS_ATTEMPTS, path, sizeof(path));
  int n = snprintf(text, sizeof(text), "%u\n", attempts_of(jb->dir) + 1);
  if (ts_file_write(path, text, (size_t)n, err) != 0)
    jobs_log(j, "job %" PRIu64 ": cannot count its run (%s): a job that crashes the coordinator may be run again "
             "and again", jb->id, err);
}

void jobs_attempt_end(ts_jobs *j, const job *jb) {
  char path[JOBS_PATH + 16];
  jobs_file_path(jb, JOBS_ATTEMPTS, path, sizeof(path));
  if (unlink(path) != 0 && errno != ENOENT)
    jobs_log(j, "job %" PRIu64 ": cannot remove %s: %s; a restart may count a run that ended as a crash", jb->id,
             path, strerror(errno));
}

/* An unfinished job the coordinator died in JOBS_MAX_CRASHES times is
 * recorded as failed, with why, before it is loaded (and queued again). */
static void set_aside_crasher(ts_jobs *j, job *jb) {
  char path[JOBS_PATH + 16], err[TS_ERR_LEN];
  struct stat st;
  jobs_file_path(jb, "state", path, sizeof(path));
  unsigned n = attempts_of(jb->dir);
  if (n < JOBS_MAX_CRASHES || lstat(path, &st) == 0) return;
  char text[TS_ERR_LEN];
  int len = snprintf(text, sizeof(text),
                     "failed: the coordinator stopped without ending it %u times while it ran (a crash, a kill, "
                     "or running out of memory): set aside instead of run again; check its size against the "
                     "machine's memory, then resubmit\n", n);
  if (ts_file_write(path, text, (size_t)len, err) != 0) {
    jobs_log(j, "job %" PRIu64 ": cannot set it aside after %u crashed runs: %s; it runs again", jb->id, n, err);
    return;
  }
  jobs_log(j, "job %" PRIu64 ": the coordinator stopped %u times while running it: set aside as failed", jb->id, n);
  drop_job_checkpoint(j, jb);
  jobs_attempt_end(j, jb);
}

/* Where input k of a job lives: ref.EXT for the first, NAME.EXT after. */
void jobs_input_path(const job *jb, const ts_engine_inputs *names, int k, char *out, size_t cap) {
  if (k == 0) snprintf(out, cap, "%s/ref.%s", jb->dir, jb->ref_ext);
  else snprintf(out, cap, "%s/%s.%s", jb->dir, names->name[k], jb->more_ext[k - 1]);
}

/* Makes path and the directories above it that are missing, each one
 * made durably (make_dir). */
static int mkdir_p(const char *path, char *err) {
  char buf[JOBS_PATH + 16];
  snprintf(buf, sizeof(buf), "%s", path);
  size_t n = strlen(buf);
  for (size_t i = 1; i <= n; i++) {
    if (buf[i] != '/' && buf[i] != '\0') continue;
    char c = buf[i];
    buf[i] = '\0';
    struct stat st;
    if (stat(buf, &st) != 0 && make_dir(buf, err) != 0) return TS_EIO;
    buf[i] = c;
  }
  return 0;
}

/* Judges job directory dir by its files (spool.h). */
static int judge_job_dir(const char *dir, ts_spool_job *rec, char *err) {
  enum { NFILES = 5 };
  static const struct {
    const char *name;
    size_t cap; /* more than the file's writer ever puts there */
  } files[NFILES] = {{"job.spec", TS_SPEC_MAX}, {"client", TS_SPOOL_CLIENT_LEN}, {"ref.ext", TS_EXT_LEN},
                     {"inputs", TS_ENGINE_MAX_INPUTS * (TS_ENGINE_KEY_LEN + TS_EXT_LEN + 2)},
                     {"state", TS_ERR_LEN + 32}};
  ts_spool_files f = {0};
  ts_spool_file *slot[NFILES] = {&f.spec, &f.client, &f.ref_ext, &f.inputs, &f.state};
  uint8_t *buf[NFILES] = {NULL};
  char why[NFILES][TS_ERR_LEN], path[JOBS_PATH + 32];
  for (int i = 0; i < NFILES; i++) {
    snprintf(path, sizeof(path), "%s/%s", dir, files[i].name);
    read_spool_file(path, files[i].cap, slot[i], &buf[i], why[i]);
  }
  struct stat st;
  snprintf(path, sizeof(path), "%s/%s", dir, JOBS_CHECKPOINT);
  f.checkpoint = lstat(path, &st) == 0;
  int rc = ts_spool_read_job(dir, &f, rec, err);
  for (int i = 0; i < NFILES; i++) free(buf[i]);
  return rc;
}

/* Modification time of a job's file (NULL: of its directory), ms since
 * the epoch; 0 if there is none. */
static uint64_t file_ms(const job *jb, const char *name) {
  char path[JOBS_PATH + 32];
  struct stat st;
  if (name != NULL) jobs_file_path(jb, name, path, sizeof(path));
  else snprintf(path, sizeof(path), "%s", jb->dir);
  if (stat(path, &st) != 0) return 0;
  return (uint64_t)st.st_mtim.tv_sec * 1000u + (uint64_t)(st.st_mtim.tv_nsec / 1000000);
}

/* A reloaded job's times: submitted when its job.spec was written (last
 * of a submission), ended when its state was (its directory's time for a
 * job kept as failed without one: the spool says no better). When it
 * started is not kept. */
static void note_times(job *jb) {
  jb->st.submitted_ms = file_ms(jb, "job.spec");
  if (!job_final(jb)) return;
  jb->st.ended_ms = file_ms(jb, "state");
  if (jb->st.ended_ms == 0) jb->st.ended_ms = file_ms(jb, NULL);
}

/* Reloads one job directory; unfinished jobs queue again, damaged ones
 * are kept as spool.h says, with a log line. */
static void load_job(ts_jobs *j, uint64_t id) {
  /* Ids are never reused, not even an unacknowledged submission's: its
   * directory is still there and a new job could not be created in it. */
  if (id >= j->next_id) j->next_id = id + 1;
  job *jb = calloc(1, sizeof(*jb));
  ts_spool_job *rec = malloc(sizeof(*rec));
  char err[TS_ERR_LEN];
  if (jb == NULL || rec == NULL) {
    jobs_log(j, "out of memory loading job %" PRIu64 " from the spool: it is left out until a restart", id);
    free(jb);
    free(rec);
    return;
  }
  jb->id = id;
  snprintf(jb->dir, sizeof(jb->dir), "%s/jobs/%" PRIu64, j->spool, id);
  set_aside_crasher(j, jb);
  if (judge_job_dir(jb->dir, rec, err) != 0) {
    /* Never acknowledged: its files go, its id stays taken (last-id). */
    jobs_log(j, "%s; removing it", err);
    jobs_remove_dir(jb->dir);
    free(jb);
    free(rec);
    return;
  }
  if (rec->note[0] != '\0') jobs_log(j, "job %" PRIu64 ": %s", id, rec->note);
  if (rec->has_spec) jb->spec = rec->spec;
  snprintf(jb->client, sizeof(jb->client), "%s", rec->client);
  snprintf(jb->ref_ext, sizeof(jb->ref_ext), "%s", rec->ref_ext);
  memcpy(jb->more_ext, rec->more_ext, sizeof(jb->more_ext));
  jb->st.id = id;
  jb->st.state = (uint8_t)rec->state;
  jb->st.levels = rec->has_spec ? (uint8_t)jb->spec.engine->levels(&jb->spec.params) : 0;
  jb->st.permille = rec->state == TS_JOB_DONE ? 1000 : 0;
  jb->st.eta_ms = UINT32_MAX;
  snprintf(jb->st.text, sizeof(jb->st.text), "%s", rec->text);
  free(rec);
  note_times(jb);
  jobs_describe(jb);
  jb->bytes = dir_bytes(jb->dir);
  j->spool_bytes += jb->bytes;
  client_share *cs = jobs_share_of(j, jb->client);
  if (cs && !job_final(jb)) cs->unfinished++;
  jobs_append(j, jb);
}

/* The highest id ever given out, kept apart from the job directories so a
 * deleted job's id is not given out again after a restart. */
#define JOBS_LAST_ID "last-id"

/* Records id as given out, before the job that has it is acknowledged. */
int jobs_note_last_id(ts_jobs *j, uint64_t id, char *err) {
  char path[JOBS_PATH + 16], text[32];
  snprintf(path, sizeof(path), "%s/%s", j->spool, JOBS_LAST_ID);
  int n = snprintf(text, sizeof(text), "%" PRIu64 "\n", id);
  return ts_file_write(path, text, (size_t)n, err);
}

/* Numbers new jobs after last-id (next_id is already past every job
 * directory). Without a usable last-id the job directories are all there
 * is: the ids of deleted jobs above them could come again, which the log
 * line says, with what to do about it. */
static void read_last_id(ts_jobs *j, size_t njobs) {
  char path[JOBS_PATH + 16], why[TS_ERR_LEN], err[TS_ERR_LEN];
  snprintf(path, sizeof(path), "%s/%s", j->spool, JOBS_LAST_ID);
  ts_spool_file f;
  uint8_t *buf = NULL;
  read_spool_file(path, 32, &f, &buf, why);
  uint64_t last;
  int rc = ts_spool_read_last_id(path, &f, &last, err);
  free(buf);
  if (rc == 0 && j->next_id <= last) j->next_id = last + 1;
  if (j->next_id == 0) j->next_id = 1;
  if (rc == 0 || (rc == TS_ENOENT && njobs == 0)) return; /* a new spool has none */
  jobs_log(j,
           "%s: new jobs are numbered from %" PRIu64 ", after the jobs in the spool; ids of jobs deleted "
           "above %" PRIu64 " would be given out again: if there were any, write the highest id ever given to %s",
           err, j->next_id, j->next_id - 1, path);
}

static int cmp_u64(const void *a, const void *b) {
  uint64_t x = *(const uint64_t *)a, y = *(const uint64_t *)b;
  return x < y ? -1 : x > y;
}

/* Removes what is left of a deleted job (TS_SPOOL_DELETED). */
static void finish_deletion(ts_jobs *j, const char *jobs, const char *name) {
  char path[JOBS_PATH + 16 + 256];
  snprintf(path, sizeof(path), "%s/%s", jobs, name);
  if (jobs_remove_dir(path) == 0) jobs_log(j, "removed %s, what a deletion cut short by a crash left", path);
  else jobs_log(j, "cannot remove %s, a deleted job's files: %s; remove it by hand", path, strerror(errno));
}

int jobs_load_spool(ts_jobs *j, char *err) {
  char path[JOBS_PATH + 16];
  snprintf(path, sizeof(path), "%s/jobs", j->spool);
  DIR *d = opendir(path);
  if (d == NULL) return ts_error(err, TS_EIO, "cannot read the spool %s: %s", path, strerror(errno));
  uint64_t *ids = NULL;
  size_t n = 0, cap = 0;
  struct dirent *e;
  while ((e = readdir(d)) != NULL) {
    uint64_t id;
    ts_spool_entry kind = ts_spool_entry_of(e->d_name, &id);
    if (kind == TS_SPOOL_DELETED) {
      if (id >= j->next_id) j->next_id = id + 1;
      finish_deletion(j, path, e->d_name);
    }
    if (kind != TS_SPOOL_JOB) continue;
    if (n == cap) {
      cap = cap ? 2 * cap : 64;
      uint64_t *p = realloc(ids, cap * sizeof(*ids));
      if (p == NULL) break;
      ids = p;
    }
    ids[n++] = id;
  }
  closedir(d);
  if (n > 0) qsort(ids, n, sizeof(*ids), cmp_u64);
  for (size_t i = 0; i < n; i++) load_job(j, ids[i]);
  free(ids);
  read_last_id(j, n);
  return 0;
}

/* One coordinator per spool: two would both run its queued jobs, write
 * the same files and give out the same ids. The lock is flock's, on
 * SPOOL/lock: the kernel drops it when its holder dies, however it dies,
 * so the file a killed coordinator leaves never blocks the next one. The
 * holder writes its pid there, for the message that refuses a second. */
#define JOBS_LOCK "lock"

/* The pid in the lock file open as fd; 0 while there is none (its holder
 * is between its flock and its write). */
static long lock_holder(int fd) {
  char text[32], *end;
  ssize_t n = pread(fd, text, sizeof(text) - 1, 0);
  if (n <= 0) return 0;
  text[n] = '\0';
  long pid = strtol(text, &end, 10);
  return pid > 0 && *end == '\n' ? pid : 0;
}

/* Why the lock at path, open as fd, of spool is not ours: its holder,
 * named. */
static int lock_refused(int fd, const char *spool, const char *path, char *err) {
  long pid = 0;
  const struct timespec tick = {0, 10 * 1000 * 1000};
  for (int i = 0; i < 100 && (pid = lock_holder(fd)) == 0; i++) nanosleep(&tick, NULL);
  char holder[64] = "its pid not written yet";
  if (pid > 0) snprintf(holder, sizeof(holder), "pid %ld", pid);
  return ts_error(err, TS_EINVAL,
                  "the spool %s is in use by another texsyn-server (%s, holding %s): stop that one first, or "
                  "give this one another --spool", spool, holder, path);
}

static int lock_spool(ts_jobs *j, char *err) {
  char path[JOBS_PATH + 16], text[32];
  snprintf(path, sizeof(path), "%s/%s", j->spool, JOBS_LOCK);
  j->lock_fd = open(path, O_RDWR | O_CREAT | O_CLOEXEC, 0600);
  if (j->lock_fd < 0) return ts_error(err, TS_EIO, "cannot lock the spool: cannot open %s: %s", path, strerror(errno));
  if (flock(j->lock_fd, LOCK_EX | LOCK_NB) != 0)
    return errno == EWOULDBLOCK ? lock_refused(j->lock_fd, j->spool, path, err)
                                : ts_error(err, TS_EIO, "cannot lock the spool: %s: %s", path, strerror(errno));
  int n = snprintf(text, sizeof(text), "%ld\n", (long)getpid());
  if (ftruncate(j->lock_fd, 0) != 0 || write(j->lock_fd, text, (size_t)n) != n)
    return ts_error(err, TS_EIO, "cannot lock the spool: cannot write %s: %s", path, strerror(errno));
  return 0;
}

/* The spool's directories, made if missing, and its lock. */
int jobs_open_spool(ts_jobs *j, char *err) {
  char path[JOBS_PATH + 16];
  snprintf(path, sizeof(path), "%s/jobs", j->spool);
  char why[TS_ERR_LEN];
  if (mkdir_p(path, why) != 0) return ts_error(err, TS_EIO, "cannot create the spool %s: %s", path, why);
  return lock_spool(j, err);
}

/* The files of an admitted job: its inputs, client, ref.ext, inputs (with
 * more than one) and, last, job.spec - a job directory without it was
 * never accepted. */
int jobs_write_files(job *jb, const char *client, const ts_msg_submit *m, const ts_engine_inputs *names,
                           char *err) {
  char path[JOBS_PATH + 64], list[TS_ENGINE_MAX_INPUTS * (TS_ENGINE_KEY_LEN + TS_EXT_LEN + 2)];
  int rc = 0;
  size_t nl = 0;
  rc = make_dir(jb->dir, err);
  jobs_input_path(jb, names, 0, path, sizeof(path));
  if (rc == 0) rc = ts_file_write(path, m->ref, m->ref_len, err);
  for (int k = 1; rc == 0 && k < names->n; k++) {
    jobs_input_path(jb, names, k, path, sizeof(path));
    rc = ts_file_write(path, m->more[k - 1].data, m->more[k - 1].len, err);
    nl += (size_t)snprintf(list + nl, sizeof(list) - nl, "%s=%s\n", names->name[k], jb->more_ext[k - 1]);
  }
  jobs_file_path(jb, "client", path, sizeof(path));
  if (rc == 0) rc = ts_file_write(path, client, strlen(client), err);
  jobs_file_path(jb, "ref.ext", path, sizeof(path));
  if (rc == 0) rc = ts_file_write(path, jb->ref_ext, strlen(jb->ref_ext), err);
  jobs_file_path(jb, "inputs", path, sizeof(path));
  if (rc == 0 && names->n > 1) rc = ts_file_write(path, list, nl, err);
  char text[TS_SPEC_MAX];
  int n = ts_jobspec_format(&jb->spec, text, sizeof(text));
  jobs_file_path(jb, "job.spec", path, sizeof(path));
  if (rc == 0) rc = n < 0 ? ts_error(err, TS_ETOOBIG, "job spec too long") : ts_file_write(path, text, (size_t)n, err);
  return rc;
}

/* Deletes a job's directory (lock held): renamed to ID.deleted first, the
 * one step that takes the job out of the spool (a restart finishes a
 * removal a crash cut short, spool.h), and that rename made durable before
 * the deletion is acknowledged; then its files go. */
int jobs_discard_dir(ts_jobs *j, const job *jb, char *err) {
  char gone[sizeof(jb->dir) + sizeof(TS_SPOOL_DELETED_SUFFIX)];
  snprintf(gone, sizeof(gone), "%s%s", jb->dir, TS_SPOOL_DELETED_SUFFIX);
  if (rename(jb->dir, gone) != 0) return ts_error(err, TS_EIO, "cannot remove %s: %s", jb->dir, strerror(errno));
  if (ts_parent_sync(gone) != 0) {
    int e = errno;
    /* Put back: the job stays, rather than come back after a power loss. */
    if (rename(gone, jb->dir) == 0)
      return ts_error(err, TS_EIO, "cannot remove %s: syncing its parent: %s", jb->dir, strerror(e));
    jobs_log(j, "job %" PRIu64 " deleted, but its deletion may not survive a power loss: syncing the parent of %s: "
             "%s", jb->id, gone, strerror(e));
  }
  if (jobs_remove_dir(gone) != 0)
    jobs_log(j, "job %" PRIu64 " deleted, but %s cannot be removed: %s; a restart tries again", jb->id, gone,
             strerror(errno));
  return 0;
}
