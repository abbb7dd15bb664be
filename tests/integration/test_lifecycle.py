"""Lifecycle faults a long-running service meets: the coordinator stopped
with jobs running (SIGTERM: each job checkpoints where it is, then the
daemon exits; a restart resumes there) or killed while writing a result,
clients killed mid-upload or while watching, a spool whose disk fills up,
and a `--server` or `-o` that cannot work found before any synthesis.
Each ends with nothing lost and a message that says what happened."""
import ctypes
import os
import platform
import re
import signal
import time

import pytest

from conftest import BUILD, Daemon, SANITIZED, jobs_listed, shutdown_all, synth

SIZE = (192, 144) if SANITIZED else (384, 288)
JOB = ["--size", "%dx%d" % SIZE, "--usage-weight", "1"]


def ref_of(data):
    return data / "textures" / "brick.png"


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

def job_in_level_0(texsyn, data, cluster, tmp_path, *server_args):
    """A cluster running the JOB, just inside level 0; returns the embedded
    run's bytes and the job's id."""
    expected = tmp_path / "expected.png"
    synth(texsyn, ref_of(data), expected, SIZE, *JOB[2:])
    cluster.start(2, 1, *server_args)
    job_id = cluster.submit(ref_of(data), *JOB)
    cluster.server.wait_log(rf"job {job_id}: checkpoint after level 1 ")
    return expected.read_bytes(), job_id


@pytest.mark.sanitize
def test_sigterm_checkpoints_the_running_job_and_a_restart_resumes_it_there(texsyn, data, cluster, tmp_path):
    """No checkpoints inside levels (--checkpoint-interval 0): the only one
    inside level 0 is the one the stop writes, and the restart goes on
    from exactly that step."""
    args = ["--calibrate-ms", "50", "--checkpoint-interval", "0"]
    expected, job_id = job_in_level_0(texsyn, data, cluster, tmp_path, *args)
    rc, took = sigterm(cluster.server, timeout=15)
    log = cluster.server.read_log()
    assert rc == 0, log
    assert "stopping: 1 running job to checkpoint" in log, log
    saved = re.search(rf"job {job_id}: checkpoint inside level 0 at step (\d+) of (\d+)", log)
    assert saved, log
    assert re.search(rf"job {job_id}: stopped at level 0, step {saved.group(1)} of {saved.group(2)}, checkpoint "
                     r"saved; a restart resumes it there", log), log
    cluster.restart_server(*args)
    w = cluster.texsyn("watch", job_id, "--quiet", check=False, timeout=300)
    log2 = cluster.server.read_log()
    assert w.returncode == 0, w.stderr + log2
    resumed = re.search(RESUMED_AT.format(id=job_id), log2)
    assert resumed and resumed.groups() == saved.groups(), log2
    assert fetch_bytes(cluster, job_id, tmp_path) == expected


def test_sigterm_with_a_step_that_cannot_end_waits_only_the_grace(texsyn, data, cluster, tmp_path):
    """Both workers stalled (SIGSTOP): the step under way cannot end, so
    the coordinator waits --stop-grace, says so and exits; the restart
    resumes from the last checkpoint written, with the same bytes."""
    args = ["--calibrate-ms", "50", "--stop-grace", "1"]
    expected, job_id = job_in_level_0(texsyn, data, cluster, tmp_path, *args)
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
    cluster.restart_server(*args)
    w = cluster.texsyn("watch", job_id, "--quiet", check=False, timeout=300)
    assert w.returncode == 0, w.stderr + cluster.server.read_log()
    assert re.search(rf"job {job_id}: resuming (inside|after) level", cluster.server.read_log())
    assert fetch_bytes(cluster, job_id, tmp_path) == expected


# ---- the coordinator killed while writing a result -------------------------

@pytest.mark.parametrize("at", ["out.", "state"])
def test_coordinator_killed_while_writing_a_result_reruns_the_job(texsyn, data, cluster, tmp_path, at):
    """Killed at the rename that would publish the result image (its bytes
    written under a temporary name), or the job's state file (the results
    published, the job not yet marked done): either way the restart runs
    the job again and serves the embedded run's bytes, and no temporary
    file stays behind. The kill comes from a preloaded rename()
    (tests/preload/kill_at_rename.c). A small job: only its end matters."""
    small = (192, 144)
    expected = tmp_path / "expected.png"
    synth(texsyn, ref_of(data), expected, small)
    shim = BUILD / "tests" / "libkill_at_rename.so"
    assert shim.exists(), f"{shim} is missing: run make"
    cluster.worker(1)
    args = [BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", cluster.tmp / "spool", "--calibrate-ms",
            "50", "--workers", cluster.workers[0].addr]
    cluster.server = Daemon(["env", f"LD_PRELOAD={shim}", "TEXSYN_KILL_AT_RENAME=/jobs/1/" + at, *args],
                            cluster.tmp / "server.log")
    cluster.wait_ready(1)
    job_id = cluster.submit(ref_of(data), "--size", "%dx%d" % small)
    assert job_id == "1"
    cluster.server.expect_signal(signal.SIGKILL)  # raised by the shim
    assert cluster.server.proc.wait(timeout=120) == -signal.SIGKILL
    job_dir = cluster.tmp / "spool" / "jobs" / job_id
    assert any(".tmp" in p.name for p in job_dir.iterdir()) or at == "state", sorted(job_dir.iterdir())
    cluster.restart_server("--calibrate-ms", "50")
    w = cluster.texsyn("watch", job_id, "--quiet", check=False, timeout=300)
    assert w.returncode == 0, w.stderr + cluster.server.read_log()
    assert fetch_bytes(cluster, job_id, tmp_path) == expected.read_bytes()
    assert not [p.name for p in job_dir.iterdir() if ".tmp" in p.name]


# ---- a job that crashes the coordinator -----------------------------------------

def kill9(daemon):
    daemon.proc.send_signal(signal.SIGKILL)
    daemon.proc.wait()
    daemon.stop()


def test_a_job_the_coordinator_died_in_twice_is_set_aside_as_failed(texsyn, data, cluster, tmp_path):
    """Killed while the job runs, the coordinator resumes it once; killed in
    it again, a restart records it failed with the reason instead of
    running it a third time (as a job that runs it out of memory would
    crash it for ever). Other jobs run."""
    cluster.start(2, 1, "--calibrate-ms", "50")
    job_id = cluster.submit(ref_of(data), *JOB)
    attempts = cluster.tmp / "spool" / "jobs" / job_id / "attempts"
    cluster.server.wait_log(rf"job {job_id}: checkpoint after level 1 ")
    assert attempts.read_text() == "1\n"
    kill9(cluster.server)
    cluster.restart_server("--calibrate-ms", "50")
    cluster.server.wait_log(rf"job {job_id}: resuming")
    assert attempts.read_text() == "2\n"
    kill9(cluster.server)
    cluster.restart_server("--calibrate-ms", "50", log="server3.log")
    log = cluster.server.wait_log(rf"job {job_id}: the coordinator stopped 2 times while running it: set aside")
    assert log
    status = cluster.texsyn("status", job_id).stdout
    assert " failed" in status and "stopped without ending it 2 times" in status, status
    assert not attempts.exists()
    assert not (attempts.parent / "checkpoint").exists()
    small = tmp_path / "small.png"
    synth(texsyn, ref_of(data), small, (96, 64), "--levels", "3")
    other = cluster.submit(ref_of(data), "--size", "96x64", "--levels", "3")
    cluster.texsyn("watch", other, "--quiet")
    assert fetch_bytes(cluster, other, tmp_path) == small.read_bytes()
    assert not (cluster.tmp / "spool" / "jobs" / other / "attempts").exists()  # a run that ended


@pytest.mark.sanitize
def test_the_spool_is_owner_only(texsyn, data, cluster, tmp_path):
    """Directories 0700, files 0600, whatever umask the coordinator was
    started with (the test's is usually 022)."""
    old = os.umask(0o022)
    try:
        cluster.start(1, 1)
    finally:
        os.umask(old)
    job_id = cluster.submit(ref_of(data), "--size", "96x64", "--levels", "3")
    cluster.texsyn("watch", job_id, "--quiet")
    spool = cluster.tmp / "spool"
    paths = [spool, *spool.rglob("*")]
    assert len(paths) > 6, paths
    for p in paths:
        mode = os.stat(p).st_mode & 0o777
        assert mode == (0o700 if p.is_dir() else 0o600), f"{p}: {oct(mode)}"


# ---- clients killed ---------------------------------------------------------

class HoldingProxy:
    """Between a client and the coordinator: forwards the coordinator's
    bytes, and the client's until `limit` have gone through, then holds
    the rest (an upload cut off mid-frame). `held` is set once it holds."""

    def __init__(self, target, limit):
        import socket
        import threading
        self.target, self.limit, self.held = target, limit, threading.Event()
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(4)
        self.addr = "127.0.0.1:%d" % self.sock.getsockname()[1]
        threading.Thread(target=self.serve, daemon=True).start()

    def serve(self):
        import socket
        import threading
        a, _ = self.sock.accept()
        host, port = self.target.rsplit(":", 1)
        b = socket.create_connection((host, int(port)))
        threading.Thread(target=self.pump, args=(b, a, None), daemon=True).start()
        self.pump(a, b, self.limit)

    def pump(self, src, dst, limit):
        sent = 0
        try:
            while data := src.recv(65536):
                if limit is not None and sent + len(data) > limit:
                    dst.sendall(data[:limit - sent])
                    self.held.set()
                    while src.recv(65536):  # until the client dies
                        pass
                    break
                dst.sendall(data)
                sent += len(data)
        except OSError:
            pass
        shutdown_all(src, dst)  # a close() would wait for the other pump's recv


def jobs_of(cluster):
    return jobs_listed(cluster.texsyn("status").stdout)


def test_client_killed_mid_upload_leaves_no_job(texsyn, data, cluster, tmp_path):
    """The coordinator gets part of the submission (the reference cut off
    mid-frame), then the client dies: no job, no spool directory, and the
    next client is served."""
    import subprocess
    cluster.start(1, 1)
    proxy = HoldingProxy(cluster.server.addr, 40000)
    p = subprocess.Popen([str(BUILD / "texsyn"), "synth", "--server", proxy.addr, "--ref", str(ref_of(data)), "-o",
                          str(tmp_path / "never.png"), *JOB], stderr=subprocess.PIPE, text=True)
    assert proxy.held.wait(30), "the upload never reached 40000 bytes"
    p.kill()
    p.wait()
    cluster.server.wait_log(r"client \S+ \(.*\) went away in the middle of a message \(\d+ bytes of it received\): "
                            r"dropped, nothing of it was accepted", timeout=30)
    assert cluster.server.alive()
    assert jobs_of(cluster) == [], "a job appeared from a cut-off upload"
    assert not list((cluster.tmp / "spool" / "jobs").iterdir())
    job_id = cluster.submit(ref_of(data), "--size", "128x96", "--levels", "3")
    assert cluster.texsyn("watch", job_id, "--quiet", check=False, timeout=120).returncode == 0


def test_client_killed_while_watching_loses_nothing(texsyn, data, cluster, tmp_path):
    """`texsyn synth` killed while it waits for its job: the job runs on
    and a later client fetches the embedded run's bytes."""
    import subprocess
    expected = tmp_path / "expected.png"
    synth(texsyn, ref_of(data), expected, SIZE, *JOB[2:])
    cluster.start(2, 1, "--calibrate-ms", "50")
    p = subprocess.Popen([str(BUILD / "texsyn"), "synth", "--server", cluster.server.addr, "--ref",
                          str(ref_of(data)), "-o", str(tmp_path / "never.png"), *JOB, "--quiet"])
    m = cluster.server.wait_log(r"job (\d+): checkpoint after level 2 ")
    p.kill()
    p.wait()
    job_id = m.group(1)
    w = cluster.texsyn("watch", job_id, "--quiet", check=False, timeout=300)
    assert w.returncode == 0, w.stderr + cluster.server.read_log()
    assert fetch_bytes(cluster, job_id, tmp_path) == expected.read_bytes()
    assert not (tmp_path / "never.png").exists()


# ---- the spool's disk full --------------------------------------------------

class Tmpfs:
    """A small tmpfs mounted for the spool (the suite runs as root)."""

    def __init__(self, path, size):
        import subprocess
        path.mkdir()
        p = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)], capture_output=True,
                           text=True)
        if p.returncode != 0:
            pytest.fail(f"cannot mount a tmpfs for the full-disk test (needs root): {p.stderr}", pytrace=False)
        self.path = path

    def fill(self, name="filler"):
        """Writes until not one more byte fits: big pieces, then smaller."""
        import os
        fd = os.open(self.path / name, os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
        try:
            for piece in (1 << 20, 4096, 1):
                try:
                    while True:
                        os.write(fd, b"\0" * piece)
                except OSError:
                    pass
        finally:
            os.close(fd)

    def umount(self):
        import subprocess
        subprocess.run(["umount", "-l", str(self.path)], check=False)


def test_full_spool_disk_refuses_or_fails_with_the_reason_and_recovers(texsyn, data, cluster, tmp_path):
    """On a full disk a submission is refused and a running job whose
    result cannot be written fails, both saying the disk is full; the
    daemon serves on, and once space is freed the same job gives the
    embedded run's bytes."""
    expected = tmp_path / "expected.png"
    synth(texsyn, ref_of(data), expected, SIZE, *JOB[2:])
    disk = Tmpfs(tmp_path / "spool", "16m")
    try:
        cluster.start(1, 1, "--calibrate-ms", "50")
        disk.fill()
        p = cluster.texsyn("synth", "--ref", ref_of(data), "-o", tmp_path / "x.png", *JOB, "--detach", check=False)
        assert p.returncode != 0 and "No space left on device" in p.stderr, p.stderr
        assert jobs_of(cluster) == []
        (disk.path / "filler").unlink()
        job_id = cluster.submit(ref_of(data), *JOB)
        disk.fill()  # while the job runs: its checkpoints and result find the disk full
        w = cluster.texsyn("watch", job_id, "--quiet", check=False, timeout=300)
        status = cluster.texsyn("status", job_id).stdout
        assert w.returncode != 0 and "failed" in status and "No space left on device" in status, status
        log = cluster.server.read_log()
        assert "no checkpoint" in log and "the job goes on without it" in log, log
        assert cluster.server.alive()
        (disk.path / "filler").unlink()
        cluster.texsyn("delete", job_id)
        job_id = cluster.submit(ref_of(data), *JOB)
        assert cluster.texsyn("watch", job_id, "--quiet", check=False, timeout=300).returncode == 0
        assert fetch_bytes(cluster, job_id, tmp_path) == expected.read_bytes()
    finally:
        cluster.stop()
        disk.umount()


def test_full_disk_fails_every_image_format_with_the_reason(texsyn, data, tmp_path):
    """Each format's writer meets the full disk and says so; none reports
    success over an empty file (the PNG writer did) or exits the process
    (libjpeg's did), and no temporary file stays behind."""
    disk = Tmpfs(tmp_path / "disk", "1m")
    try:
        disk.fill()
        for ext in ("png", "jpg", "tif", "exr"):
            p = subprocess_run(texsyn, "synth", "--embedded", "--ref", ref_of(data), "-o", disk.path / f"out.{ext}",
                               "--size", "128x96", "--levels", "3", "--quiet")
            assert p.returncode == 1 and f"out.{ext}: cannot write image: " in p.stderr, (ext, p.stderr)
            assert sorted(f.name for f in disk.path.iterdir()) == ["filler"], (ext, p.stderr)
    finally:
        disk.umount()


# ---- a --server or -o that cannot work, found before the job runs ------------

def test_unwritable_output_is_refused_before_any_synthesis(texsyn, data, tmp_path):
    """Today's runs of several seconds fail at once: a missing directory,
    a path through a file, a directory as -o, for the image and the side
    outputs, embedded and against a coordinator address."""
    (tmp_path / "file").write_text("")
    big = ["--size", "2048x2048"]  # minutes of work, were it to run
    before = "(found before the job ran; nothing was done)"
    cases = [(["-o", tmp_path / "missing" / "out.png"],
              f"cannot write {tmp_path / 'missing' / 'out.png'}: No such file or directory {before}"),
             (["-o", tmp_path / "file" / "out.png"], f"cannot write {tmp_path / 'file' / 'out.png'}: Not a directory {before}"),
             (["-o", tmp_path], f"cannot write {tmp_path}: it is a directory; name a file in it"),
             (["-o", tmp_path / "ok.png", "--report", tmp_path / "missing" / "r.json"],
              f"cannot write {tmp_path / 'missing' / 'r.json'}: No such file or directory {before}")]
    for where in (["--embedded"], ["--server", "127.0.0.1:1"]):
        for out, why in cases:
            t0 = time.time()
            p = subprocess_run(texsyn, "synth", "--ref", ref_of(data), *out, *big, *where)
            assert p.returncode == 1, (where, why, p.returncode, p.stderr)
            assert why in p.stderr, (where, why, p.stderr)
            assert time.time() - t0 < 5, "the check came after the synthesis"
    assert not (tmp_path / "ok.png").exists()


def test_unreachable_server_is_named_before_any_upload(texsyn, data, tmp_path, monkeypatch):
    p = subprocess_run(texsyn, "synth", "--server", "127.0.0.1:1", "--ref", ref_of(data), "-o", tmp_path / "o.png",
                       *JOB)
    assert p.returncode == 1, p.stderr
    assert "cannot connect to 127.0.0.1:1" in p.stderr and "no job was submitted" in p.stderr, p.stderr
    monkeypatch.setenv("TEXSYN_SERVER", "127.0.0.1:1")
    p = subprocess_run(texsyn, "synth", "--ref", ref_of(data), "-o", tmp_path / "o.png", *JOB)
    assert p.returncode == 1 and "from $TEXSYN_SERVER" in p.stderr and "(no job was submitted; --embedded runs it here)" in p.stderr, p.stderr
    assert not (tmp_path / "o.png").exists()


def subprocess_run(exe, *args):
    import subprocess
    return subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True, timeout=120)


# ---- a stop signal that lands on any thread -------------------------------

def tgkill(pid, tid, sig):
    """Sends sig to one thread of another process (tgkill(2)): the kernel
    may hand a `kill` to any thread, this picks which."""
    libc = ctypes.CDLL(None, use_errno=True)
    SYS_tgkill = {"x86_64": 234, "aarch64": 131}[platform.machine()]
    assert libc.syscall(SYS_tgkill, pid, tid, sig) == 0, os.strerror(ctypes.get_errno())


def threads_taking(pid, sig):
    """The threads of pid but its main one that do not block sig (a signal
    sent to a thread that blocks it waits there; `kill` never picks one)."""
    def blocks(tid):
        status = open(f"/proc/{pid}/task/{tid}/status").read()
        return int(re.search(r"SigBlk:\s*([0-9a-f]+)", status).group(1), 16) >> (sig - 1) & 1
    return sorted(t for t in map(int, os.listdir(f"/proc/{pid}/task")) if t != pid and not blocks(t))


@pytest.mark.parametrize("daemon", ["worker", "server"])
def test_sigterm_on_any_thread_stops_the_daemon(cluster, daemon):
    """SIGTERM delivered to a thread other than the one in accept() (a scan
    thread of the worker, a pool or page thread of the coordinator) still
    stops the daemon at once: the hostile run once saw a worker sleep in
    accept() through it. The signal goes to the oldest such thread but main
    (the worker's first scan thread)."""
    if daemon == "worker":  # alone: a coordinator's connection would wake accept()
        d = cluster.worker(2)
    else:
        d = cluster.start(1, 2, "--http", "127.0.0.1:0").server
    tids = threads_taking(d.proc.pid, signal.SIGTERM)
    assert tids, f"{daemon} runs no thread but its main one that takes SIGTERM"
    d.expect_signal(signal.SIGTERM)
    tgkill(d.proc.pid, tids[0], signal.SIGTERM)
    assert d.proc.wait(timeout=10) == 0
    assert "shutting down" in d.read_log()
