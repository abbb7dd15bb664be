"""Damaged files in a stopped coordinator's spool (server/jobs/spool.c): an
accepted job is never dropped in silence. After a restart, a job whose
job.spec or ref.ext is damaged and that still needs it is failed with a
reason naming the file (in `texsyn status` and the log); a damaged state
file reruns its job, a damaged client file only loses the job's fairness
key, a damaged last-id gives no id out twice; a directory without job.spec
(a submission cut short) goes. The jobs left alone, and the reruns, end
with the embedded run's bytes. One coordinator at a time on a spool: a
second refuses to start, naming the first."""
import re
import signal

import pytest

from conftest import BUILD, Daemon, jobs_listed, run, synth

ARGS = ["--size", "64x48", "--levels", "3"]


def ref_of(data):
    return data / "textures" / "brick.png"


def start_server(cluster, log, *extra):
    """A coordinator on the cluster's spool, as conftest's Cluster.start
    makes one."""
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", cluster.tmp / "spool",
                             *extra], cluster.tmp / log)


def submit(cluster, data):
    """`texsyn synth --detach` of the small job; its id."""
    p = cluster.texsyn("synth", "--ref", ref_of(data), "-o", cluster.tmp / "unused.png", *ARGS, "--detach")
    return p.stdout.split()[-1]


def status(cluster, job):
    """`texsyn status ID` as (state, text)."""
    line = cluster.texsyn("status", job).stdout.splitlines()[0]
    f = line.split(None, 2)
    assert f[0] == job, line
    return f[1], f[2] if len(f) > 2 else ""


def fetched(cluster, job, tmp_path):
    out = tmp_path / f"fetched-{job}.png"
    cluster.texsyn("fetch", job, "-o", out)
    return out.read_bytes()


# Not in the sanitized subset: the readers run under ASan+UBSan in
# test_spool (unit) and fuzz_spool.
def test_damaged_spool_files_after_a_restart(texsyn, data, cluster, tmp_path):
    expected = tmp_path / "expected.png"
    synth(texsyn, ref_of(data), expected, (64, 48), "--levels", "3")
    want = expected.read_bytes()

    # Jobs 1-4 finish; 5-9 stay queued behind a paused queue.
    start_server(cluster, "server1.log", "--modbus", "0", "--modbus-control", "--modbus-allow", "127.0.0.1")
    done = [submit(cluster, data) for _ in range(4)]
    assert done == ["1", "2", "3", "4"]
    for job in done:
        cluster.texsyn("watch", job, "--quiet")
    run(BUILD / "texsyn", "modbus", cluster.server.modbus, "--set", "pause=1")
    queued = [submit(cluster, data) for _ in range(5)]
    assert queued == ["5", "6", "7", "8", "9"]
    assert all(status(cluster, j)[0] == "held" for j in queued)
    cluster.server.stop()

    spool = tmp_path / "spool"
    jobs = spool / "jobs"
    d = {j: f"{jobs}/{j}" for j in map(str, range(1, 11))}
    spec = (jobs / "1" / "job.spec").read_text()
    (jobs / "1" / "job.spec").write_text(spec.replace("size=64x48", "size=64x"))
    (jobs / "2" / "state").write_text("dne\n")
    (jobs / "3" / "client").unlink()
    (jobs / "4" / "ref.ext").write_text("p/g")
    (jobs / "5" / "job.spec").write_text(spec.replace("levels=3", "levls=3"))
    (jobs / "6" / "ref.ext").write_text("p/g")
    (jobs / "7" / "state").write_bytes(b"\x00\xffgarbage")
    (jobs / "8" / "client").unlink()
    cut_short = jobs / "10"  # a submission killed before its job.spec
    cut_short.mkdir()
    (cut_short / "ref.png").write_bytes(ref_of(data).read_bytes())
    (cut_short / "client").write_text("someone")
    (spool / "last-id").write_text("9z\n")

    start_server(cluster, "server2.log")
    log = cluster.server.read_log()
    spec_error = r"job spec line \d+: [^)]*"
    expect_lines = [
        re.escape(f"job 1: kept as failed: job.spec in {d['1']} is damaged (") + spec_error +
        re.escape("); the job's results cannot be served: resubmit it"),
        re.escape(f"job 2: state in {d['2']} is damaged (it says 'dne'); the job runs again"),
        re.escape(f"job 3: client in {d['3']} is damaged (it is missing); the job counts as client '?'"),
        re.escape(f"job 4: ref.ext in {d['4']} is damaged (it says 'p/g', not a file extension); the job was "
                  "done already, and stays so"),
        re.escape(f"job 5: kept as failed: job.spec in {d['5']} is damaged (") + spec_error +
        re.escape("); the job cannot run: resubmit it"),
        re.escape(f"job 6: kept as failed: ref.ext in {d['6']} is damaged (it says 'p/g', not a file extension); "
                  "the job's reference cannot be found, so the job cannot run: resubmit it"),
        re.escape(f"job 7: state in {d['7']} is damaged (it says '\\x00\\xffgarbage'); the job runs again"),
        re.escape(f"job 8: client in {d['8']} is damaged (it is missing); the job counts as client '?'"),
        re.escape(f"{d['10']} has no job.spec: a submission cut short before it was acknowledged; removing it"),
        re.escape(f"{spool}/last-id is damaged (it says '9z', not a job id): new jobs are numbered from 11, after "
                  "the jobs in the spool; ids of jobs deleted above 10 would be given out again: if there were "
                  f"any, write the highest id ever given to {spool}/last-id"),
    ]
    for pattern in expect_lines:
        assert re.search(pattern, log), f"not logged: {pattern}\n{log}"
    assert not cut_short.exists(), "the cut-short submission stayed in the spool"
    assert "job 9:" not in log, "the sound queued job was reported damaged"

    # The failed ones say why, in `status ID` and in the listing.
    state, text = status(cluster, "1")
    assert state == "failed" and re.fullmatch(
        re.escape(f"job.spec in {d['1']} is damaged (") + spec_error +
        re.escape("); the job's results cannot be served: resubmit it"), text), text
    state, text = status(cluster, "5")
    assert state == "failed" and text.startswith(f"job.spec in {d['5']} is damaged (") and \
        text.endswith("the job cannot run: resubmit it"), text
    assert status(cluster, "6") == ("failed", f"ref.ext in {d['6']} is damaged (it says 'p/g', not a file "
                                              "extension); the job's reference cannot be found, so the job cannot "
                                              "run: resubmit it")
    listing = {r["id"]: r for r in jobs_listed(cluster.texsyn("status").stdout)}
    assert listing["5"]["state"] == "failed" and listing["5"]["engine"] == "unknown" and \
        listing["5"]["note"].startswith(f"job.spec in {d['5']} is damaged ("), listing["5"]
    refused = cluster.texsyn("fetch", "1", "-o", tmp_path / "f1.png", check=False)
    assert refused.returncode == 1 and f"job.spec in {d['1']} is damaged" in refused.stderr

    # A new job gets an id no job had; the reruns and the sound jobs end
    # with the embedded bytes, and done jobs with a damaged client or
    # ref.ext are still served.
    newest = submit(cluster, data)
    assert newest == "11", newest
    for job in ("2", "7", "8", "9", "11"):
        cluster.texsyn("watch", job, "--quiet")
        assert status(cluster, job) == ("done", ""), job
        assert fetched(cluster, job, tmp_path) == want, f"job {job} differs from the embedded run"
    for job in ("3", "4"):
        assert status(cluster, job) == ("done", "")
        assert fetched(cluster, job, tmp_path) == want, f"job {job} differs from the embedded run"

    # Restarted once more: last-id is sound again (job 11 wrote it), the
    # damaged jobs are still failed for the same reasons.
    cluster.server.stop()
    start_server(cluster, "server3.log")
    log = cluster.server.read_log()
    assert "last-id" not in log, log
    assert status(cluster, "6")[0] == "failed" and status(cluster, "2") == ("done", "")
    assert submit(cluster, data) == "12"


# ---- one coordinator per spool ---------------------------------------------------

@pytest.mark.sanitize
def test_a_second_coordinator_on_the_spool_refuses_to_start(texsyn, data, cluster, tmp_path):
    """Two coordinators on one spool would both run its jobs: the second
    refuses to start, naming the first's pid, and the first goes on
    serving. The lock dies with its holder: after a kill -9 the lock file
    it left blocks no one."""
    expected = tmp_path / "expected.png"
    synth(texsyn, ref_of(data), expected, (64, 48), "--levels", "3")
    start_server(cluster, "server1.log")
    first = cluster.server
    spool = tmp_path / "spool"
    second = run(BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", spool, check=False, timeout=20)
    assert second.returncode == 1, second
    assert second.stdout == "", second.stdout
    assert second.stderr == (f"texsyn-server: the spool {spool} is in use by another texsyn-server (pid "
                             f"{first.proc.pid}, holding {spool}/lock): stop that one first, or give this one "
                             "another --spool\n"), second.stderr
    job = submit(cluster, data)
    cluster.texsyn("watch", job, "--quiet")
    assert fetched(cluster, job, tmp_path) == expected.read_bytes()

    first.proc.send_signal(signal.SIGKILL)
    first.proc.wait()
    assert (spool / "lock").read_text() == f"{first.proc.pid}\n"  # left behind, stale
    start_server(cluster, "server2.log")
    assert (spool / "lock").read_text() == f"{cluster.server.proc.pid}\n"
    assert status(cluster, job) == ("done", "")
    assert fetched(cluster, job, tmp_path) == expected.read_bytes()
