"""Lifecycle faults a long-running service meets: the coordinator stopped
with jobs running (SIGTERM: each job checkpoints where it is, then the
daemon exits; a restart resumes there) or killed while writing a result,
clients killed mid-upload or while watching, a spool whose disk fills up,
and a `--server` or `-o` that cannot work found before any synthesis.
Each ends with nothing lost and a message that says what happened."""
import json
import re
import signal
import time

import pytest

from conftest import BUILD, Daemon, SANITIZED, synth

SIZE = (192, 144) if SANITIZED else (384, 288)
JOB = ["--size", "%dx%d" % SIZE, "--usage-weight", "1"]


def ref_of(data):
    return data / "textures" / "brick.png"


def submit_detached(cluster, data, tmp_path, job=JOB, ref=None):
    p = cluster.texsyn("synth", "--ref", ref or ref_of(data), "-o", tmp_path / "unused.png", *job, "--detach")
    return p.stdout.split()[-1]


def restart_coordinator(cluster, *server_args, log="server2.log"):
    args = [BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", cluster.tmp / "spool",
            "--workers", ",".join(w.addr for w in cluster.workers), *server_args]
    cluster.server = Daemon(args, cluster.tmp / log)


def fetch_bytes(cluster, job_id, tmp_path):
    out = tmp_path / f"fetched{job_id}.png"
    cluster.texsyn("fetch", job_id, "-o", out)
    return out.read_bytes()


def sigterm(daemon, timeout):
    """Sends SIGTERM; returns the exit status and how long the exit took."""
    t0 = time.time()
    daemon.proc.send_signal(signal.SIGTERM)
    rc = daemon.proc.wait(timeout=timeout)
    return rc, time.time() - t0


RESUMED_AT = r"job {id}: resuming inside level 0 at step (\d+) of (\d+)"


# ---- the coordinator stopped with jobs running ----------------------------

@pytest.mark.sanitize
def test_sigterm_checkpoints_the_running_job_and_a_restart_resumes_it_there(texsyn, data, cluster, tmp_path):
    """No checkpoints inside levels (--checkpoint-interval 0): the only one
    inside level 0 is the one the stop writes, and the restart goes on
    from exactly that step."""
    expected = tmp_path / "expected.png"
    synth(texsyn, ref_of(data), expected, SIZE, *JOB[2:])
    args = ["--calibrate-ms", "50", "--checkpoint-interval", "0"]
    cluster.start(2, 1, *args)
    job_id = submit_detached(cluster, data, tmp_path)
    cluster.server.wait_log(rf"job {job_id}: checkpoint after level 1 ")
    rc, took = sigterm(cluster.server, timeout=15)
    log = cluster.server.read_log()
    assert rc == 0, log
    assert "stopping: 1 running job to checkpoint" in log, log
    saved = re.search(rf"job {job_id}: checkpoint inside level 0 at step (\d+) of (\d+)", log)
    assert saved, log
    assert re.search(rf"job {job_id}: stopped at level 0, step {saved.group(1)} of {saved.group(2)}, checkpoint "
                     r"saved; a restart resumes it there", log), log
    restart_coordinator(cluster, *args)
    w = cluster.texsyn("watch", job_id, "--quiet", check=False, timeout=300)
    log2 = cluster.server.read_log()
    assert w.returncode == 0, w.stderr + log2
    resumed = re.search(RESUMED_AT.format(id=job_id), log2)
    assert resumed and resumed.groups() == saved.groups(), log2
    assert fetch_bytes(cluster, job_id, tmp_path) == expected.read_bytes()


def test_sigterm_with_a_step_that_cannot_end_waits_only_the_grace(texsyn, data, cluster, tmp_path):
    """Both workers stalled (SIGSTOP): the step under way cannot end, so
    the coordinator waits --stop-grace, says so and exits; the restart
    resumes from the last checkpoint written, with the same bytes."""
    expected = tmp_path / "expected.png"
    synth(texsyn, ref_of(data), expected, SIZE, *JOB[2:])
    args = ["--calibrate-ms", "50", "--stop-grace", "1"]
    cluster.start(2, 1, *args)
    job_id = submit_detached(cluster, data, tmp_path)
    cluster.server.wait_log(rf"job {job_id}: checkpoint after level 1 ")
    for w in cluster.workers:
        w.proc.send_signal(signal.SIGSTOP)
    try:
        rc, took = sigterm(cluster.server, timeout=15)
    finally:
        for w in cluster.workers:
            w.proc.send_signal(signal.SIGCONT)
    log = cluster.server.read_log()
    assert rc == 0 and took < 8, (took, log)
    assert "1 job did not reach a checkpoint within 1 s (--stop-grace): stopping them now" in log, log
    assert re.search(rf"job {job_id}: stopped before its step ended \(.*\); a restart resumes it from its last "
                     r"checkpoint", log), log
    restart_coordinator(cluster, *args)
    w = cluster.texsyn("watch", job_id, "--quiet", check=False, timeout=300)
    assert w.returncode == 0, w.stderr + cluster.server.read_log()
    assert re.search(rf"job {job_id}: resuming (inside|after) level", cluster.server.read_log())
    assert fetch_bytes(cluster, job_id, tmp_path) == expected.read_bytes()
