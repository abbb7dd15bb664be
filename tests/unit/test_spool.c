/* test_spool.c - what a restarted coordinator makes of a job directory and
 * of last-id (server/jobs/spool.c): jobs come back as they were; a submission
 * cut short goes; a job with a damaged file is kept, as failed when it
 * needs the file, with a reason naming it, and a note for the log; a
 * damaged state reruns the job; a damaged last-id is refused, not read as
 * some other number; a deletion cut short is told from a job. */
#include "error.h"
#include "msg.h"
#include "spool.h"
#include "ts_test.h"

#define DIR_ "/spool/jobs/7"

/* What a coordinator spooled for `texsyn synth --size 64x48 --levels 3`. */
static const char kSpec[] = "engine=mrf\nsize=64x48\nlevels=3\nwn=7\nwb=3\nparity=0\nusage_weight=0\n"
                            "coarse_weight=1\nrefine=2\nseed=1\nrgb_search=0\nmax_pixels=268435456\n"
                            "output=png\ncopy_map=\ncopy_map_raw=0\nusage_map=\nreport=0\n";

static ts_spool_file file(const char *text) { return (ts_spool_file){text, strlen(text), NULL}; }
static const ts_spool_file kMissing = {NULL, 0, NULL};
static const ts_spool_file kUnreadable = {NULL, 0, "cannot read " DIR_ "/x: Permission denied"};

/* A sound job directory, with a state file when state is not NULL. */
static ts_spool_files sound(const char *state) {
  ts_spool_files f = {file(kSpec), file("alice@host"), file("png"), kMissing, 0};
  if (state != NULL) f.state = file(state);
  return f;
}

static ts_spool_job read_ok(const ts_spool_files *f) {
  ts_spool_job job;
  char err[TS_ERR_LEN] = "";
  assert_int_equal(ts_spool_read_job(DIR_, f, &job, err), 0);
  return job;
}

static void assert_contains(const char *s, const char *part) {
  if (strstr(s, part) == NULL) fail_msg("'%s' does not contain '%s'", s, part);
}

/* --- sound directories ------------------------------------------------------ */

static void finished_jobs_come_back_as_they_were(void **state) {
  (void)state;
  ts_spool_files f = sound("done\n");
  ts_spool_job job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_DONE);
  assert_true(job.has_spec);
  assert_string_equal(job.client, "alice@host");
  assert_string_equal(job.ref_ext, "png");
  assert_string_equal(job.note, "");
  f = sound("canceled\n");
  assert_int_equal(read_ok(&f).state, TS_JOB_CANCELED);
  f = sound("failed: invalid parameters for the 64x48 reference: --wb 4\n");
  job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_FAILED);
  assert_string_equal(job.text, "invalid parameters for the 64x48 reference: --wb 4");
  assert_string_equal(job.note, "");
}

static void unfinished_jobs_queue_again(void **state) {
  (void)state;
  ts_spool_files f = sound(NULL);
  ts_spool_job job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_QUEUED);
  assert_true(job.has_spec);
  assert_string_equal(job.note, "");
  f = sound("done"); /* an edit without the newline is still done */
  assert_int_equal(read_ok(&f).state, TS_JOB_DONE);
  f = sound(NULL);
  f.ref_ext = file("png\n");
  assert_string_equal(read_ok(&f).ref_ext, "png");
}

/* --- job.spec ---------------------------------------------------------------- */

static void a_directory_without_spec_or_run_is_a_submission_cut_short(void **state) {
  (void)state;
  ts_spool_files f = sound(NULL);
  f.spec = kMissing;
  ts_spool_job job;
  char err[TS_ERR_LEN];
  assert_int_equal(ts_spool_read_job(DIR_, &f, &job, err), TS_ENOENT);
  assert_string_equal(err, DIR_ " has no job.spec: a submission cut short before it was acknowledged");
}

static void a_job_that_ran_without_spec_is_kept_failed(void **state) {
  (void)state;
  ts_spool_files f = sound(NULL);
  f.spec = kMissing;
  f.checkpoint = 1;
  ts_spool_job job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_FAILED);
  assert_string_equal(job.text, "job.spec in " DIR_ " is damaged (it is missing); the job cannot run: resubmit it");
  assert_contains(job.note, "kept as failed: job.spec in " DIR_);
  f = sound("done\n");
  f.spec = kMissing;
  job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_FAILED);
  assert_contains(job.text, "the job's results cannot be served: resubmit it");
}

static void a_damaged_spec_fails_the_job_with_the_parse_error(void **state) {
  (void)state;
  ts_spool_files f = sound(NULL);
  f.spec = file("engine=mrf\nsize=64x48\nlevls=3\n");
  ts_spool_job job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_FAILED);
  assert_false(job.has_spec);
  assert_contains(job.text, "job.spec in " DIR_ " is damaged (");
  assert_contains(job.text, "levls");
  assert_contains(job.text, "); the job cannot run: resubmit it");
  f.spec = kUnreadable;
  job = read_ok(&f);
  assert_string_equal(job.text, "job.spec in " DIR_ " is damaged (cannot read " DIR_
                                "/x: Permission denied); the job cannot run: resubmit it");
}

static void a_damaged_spec_of_a_final_job_only_makes_a_note(void **state) {
  (void)state;
  ts_spool_files f = sound("canceled\n");
  f.spec = file("size=\x01");
  ts_spool_job job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_CANCELED);
  assert_contains(job.note, "job.spec in " DIR_ " is damaged (");
  assert_contains(job.note, "the job was canceled already, and stays so");
  for (const char *p = job.note; *p; p++) assert_true((unsigned char)*p >= 0x20); /* one line */
}

/* --- state ------------------------------------------------------------------- */

static void a_garbled_state_reruns_the_job(void **state) {
  (void)state;
  const char *garbled[] = {"dne\n", "", "done\ndone\n", "failed: a\x01z\n", "\xff\xfe", "failed:x"};
  for (size_t i = 0; i < sizeof(garbled) / sizeof(garbled[0]); i++) {
    ts_spool_files f = sound(NULL);
    f.state = (ts_spool_file){garbled[i], strlen(garbled[i]), NULL};
    ts_spool_job job = read_ok(&f);
    assert_int_equal(job.state, TS_JOB_QUEUED);
    assert_string_equal(job.text, "");
    assert_contains(job.note, "state in " DIR_ " is damaged (");
    assert_contains(job.note, "the job runs again");
  }
  ts_spool_files f = sound(NULL);
  f.state = file("dne\n");
  assert_string_equal(read_ok(&f).note, "state in " DIR_ " is damaged (it says 'dne'); the job runs again");
  f.state = kUnreadable;
  assert_int_equal(read_ok(&f).state, TS_JOB_QUEUED);
}

static void a_garbled_state_with_a_damaged_spec_fails(void **state) {
  (void)state;
  ts_spool_files f = sound(NULL);
  f.state = file("don");
  f.spec = file("nonsense");
  ts_spool_job job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_FAILED);
  assert_contains(job.text, "job.spec in " DIR_ " is damaged");
  assert_contains(job.note, "state in " DIR_ " is damaged");
}

/* --- ref.ext and client ---------------------------------------------------- */

static void a_damaged_ref_ext_fails_a_job_that_must_run(void **state) {
  (void)state;
  ts_spool_files f = sound(NULL);
  f.ref_ext = file("p/g");
  ts_spool_job job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_FAILED);
  assert_string_equal(job.text, "ref.ext in " DIR_ " is damaged (it says 'p/g', not a file extension); the job's "
                                "reference cannot be found, so the job cannot run: resubmit it");
  f = sound("done\n");
  f.ref_ext = kMissing;
  job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_DONE); /* its results need no reference */
  assert_contains(job.note, "ref.ext in " DIR_ " is damaged (it is missing); the job was done already");
}

/* A job of several inputs: `inputs` names the ones after the first, in
 * the engine's order; damaged, a job that must run fails naming it. */
static void a_damaged_inputs_list_fails_a_job_that_must_run(void **state) {
  (void)state;
  static const char spec[] = "engine=stylize\nguides=1\noutput=png\n";
  ts_spool_files f = sound(NULL);
  f.spec = file(spec);
  f.inputs = file("guide_src_0=png\nguide_tgt_0=exr\n");
  ts_spool_job job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_QUEUED);
  assert_string_equal(job.more_ext[0], "png");
  assert_string_equal(job.more_ext[1], "exr");
  const ts_spool_file bad[] = {kMissing, file("guide_tgt_0=png\nguide_src_0=png\n"), file("guide_src_0=png\n"),
                               file("guide_src_0=p/g\nguide_tgt_0=png\n")};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    f.inputs = bad[i];
    job = read_ok(&f);
    assert_int_equal(job.state, TS_JOB_FAILED);
    assert_contains(job.text, "inputs in " DIR_ " is damaged (");
    assert_contains(job.text, "the job's input images cannot be found, so the job cannot run: resubmit it");
  }
  f.state = file("done\n");
  job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_DONE); /* its results need no inputs */
  assert_contains(job.note, "inputs in " DIR_ " is damaged (");
}

/* An energy job: the scene's inputs and then the image, whose line a
 * stylize job's list lacks. */
static void an_energy_job_reads_back_with_its_image(void **state) {
  (void)state;
  ts_spool_files f = sound(NULL);
  f.spec = file("engine=energy\nguides=1\nsample=2\noutput=1\n");
  f.inputs = file("guide_src_0=png\nguide_tgt_0=png\nimage=tif\n");
  ts_spool_job job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_QUEUED);
  assert_string_equal(job.spec.engine->name, "energy");
  assert_string_equal(job.more_ext[2], "tif");
  f.inputs = file("guide_src_0=png\nguide_tgt_0=png\n");
  job = read_ok(&f);
  assert_int_equal(job.state, TS_JOB_FAILED);
  assert_contains(job.text, "not the 3 lines NAME=EXT of the job's further inputs");
}

static void a_damaged_client_only_loses_the_fairness_key(void **state) {
  (void)state;
  char long_name[300];
  memset(long_name, 'x', sizeof(long_name) - 1);
  long_name[sizeof(long_name) - 1] = '\0';
  ts_spool_file bad[] = {kMissing, kUnreadable, file(long_name), {"a\0b", 3, NULL}};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    ts_spool_files f = sound(NULL);
    f.client = bad[i];
    ts_spool_job job = read_ok(&f);
    assert_int_equal(job.state, TS_JOB_QUEUED);
    assert_string_equal(job.client, TS_SPOOL_NO_CLIENT);
    assert_contains(job.note, "client in " DIR_ " is damaged (");
    assert_contains(job.note, "the job counts as client '?'");
  }
  ts_spool_files f = sound(NULL);
  f.client = file("");
  assert_string_equal(read_ok(&f).client, ""); /* a client may give no name */
}

/* --- last-id ----------------------------------------------------------------- */

static void last_id_is_a_number_or_refused(void **state) {
  (void)state;
  uint64_t id = 0;
  char err[TS_ERR_LEN];
  ts_spool_file f = file("7\n");
  assert_int_equal(ts_spool_read_last_id("/spool/last-id", &f, &id, err), 0);
  assert_int_equal(id, 7);
  f = file("18446744073709551614");
  assert_int_equal(ts_spool_read_last_id("/spool/last-id", &f, &id, err), 0);
  assert_true(id == UINT64_MAX - 1);
  const char *bad[] = {"", "\n", "0\n", "12a\n", "-3", " 5", "18446744073709551615", "99999999999999999999"};
  for (size_t i = 0; i < sizeof(bad) / sizeof(bad[0]); i++) {
    f = file(bad[i]);
    id = 42;
    assert_int_equal(ts_spool_read_last_id("/spool/last-id", &f, &id, err), TS_EFORMAT);
    assert_int_equal(id, 42);
    assert_contains(err, "/spool/last-id is damaged (it says '");
  }
  f = file("12a\n");
  ts_spool_read_last_id("/spool/last-id", &f, &id, err);
  assert_string_equal(err, "/spool/last-id is damaged (it says '12a', not a job id)");
  assert_int_equal(ts_spool_read_last_id("/spool/last-id", &kMissing, &id, err), TS_ENOENT);
  assert_string_equal(err, "/spool/last-id is missing");
  assert_int_equal(ts_spool_read_last_id("/spool/last-id", &kUnreadable, &id, err), TS_EIO);
}

/* --- names in SPOOL/jobs ------------------------------------------------------ */

static void job_directories_and_deletions_are_told_from_other_names(void **state) {
  (void)state;
  uint64_t id = 0;
  assert_int_equal(ts_spool_entry_of("7", &id), TS_SPOOL_JOB);
  assert_int_equal(id, 7);
  assert_int_equal(ts_spool_entry_of("18446744073709551615", &id), TS_SPOOL_JOB);
  assert_true(id == UINT64_MAX);
  assert_int_equal(ts_spool_entry_of("12" TS_SPOOL_DELETED_SUFFIX, &id), TS_SPOOL_DELETED);
  assert_int_equal(id, 12);
  const char *other[] = {".", "..", "", "0", "07", " 5", "+5", "-5", "5x", "5.deleted.tmp", "5.delete",
                         ".deleted", "0.deleted", "18446744073709551616", "99999999999999999999.deleted",
                         "lock", "last-id"};
  for (size_t i = 0; i < sizeof(other) / sizeof(other[0]); i++) {
    id = 42;
    if (ts_spool_entry_of(other[i], &id) != TS_SPOOL_OTHER) fail_msg("'%s' taken for a job's", other[i]);
    assert_int_equal(id, 42);
  }
}

static const struct CMUnitTest tests[] = {
    cmocka_unit_test(finished_jobs_come_back_as_they_were),
    cmocka_unit_test(unfinished_jobs_queue_again),
    cmocka_unit_test(a_directory_without_spec_or_run_is_a_submission_cut_short),
    cmocka_unit_test(a_job_that_ran_without_spec_is_kept_failed),
    cmocka_unit_test(a_damaged_spec_fails_the_job_with_the_parse_error),
    cmocka_unit_test(a_damaged_spec_of_a_final_job_only_makes_a_note),
    cmocka_unit_test(a_garbled_state_reruns_the_job),
    cmocka_unit_test(a_garbled_state_with_a_damaged_spec_fails),
    cmocka_unit_test(a_damaged_ref_ext_fails_a_job_that_must_run),
    cmocka_unit_test(a_damaged_inputs_list_fails_a_job_that_must_run),
    cmocka_unit_test(an_energy_job_reads_back_with_its_image),
    cmocka_unit_test(a_damaged_client_only_loses_the_fairness_key),
    cmocka_unit_test(last_id_is_a_number_or_refused),
    cmocka_unit_test(job_directories_and_deletions_are_told_from_other_names),
};

TS_TEST_MAIN(tests)
