"""What an operator runs against a live coordinator: spool retention
(texsyn-server --keep-ended, texsyn delete --ended) and the views of jobs
and workers (texsyn status, texsyn workers), driven on real daemons and
read from the printed text."""
import os
import re
import subprocess
import time

import pytest

from conftest import BUILD, STATUS_HEADER, jobs_listed, run, workers_listed

SMALL = ["--size", "48x32", "--levels", "2"]
MB = ["--modbus", "0", "--modbus-control", "--modbus-allow", "127.0.0.1"]


def ref_of(data):
    return data / "textures" / "brick.png"


def wait_until(what, cond, timeout=30, every=0.05):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if cond():
            return
        time.sleep(every)
    raise AssertionError(f"timed out waiting for {what}")


def submit(cluster, data, out, *args, env=None):
    p = run(BUILD / "texsyn", "synth", "--ref", ref_of(data), "-o", out, *SMALL, *args, "--detach",
            "--server", cluster.server.addr, env=env)
    return p.stdout.strip()


def pause(cluster, on):
    run(BUILD / "texsyn", "modbus", cluster.server.modbus, "--set", f"pause={int(on)}")


def listed(cluster):
    return {r["id"]: r for r in jobs_listed(cluster.texsyn("status").stdout)}


def job_dir(cluster, job):
    return cluster.tmp / "spool" / "jobs" / job


@pytest.mark.sanitize
def test_keep_ended_removes_finished_jobs_and_never_a_queued_one(data, cluster, tmp_path):
    """--keep-ended 2: a finished job's status and spool directory go about
    2 s after its end (not before: its state file's time is the end), while
    a job held by the paused queue stays however long it waits; once it has
    run, it goes too."""
    cluster.start(1, 1, *MB, "--keep-ended", "2")
    done = submit(cluster, data, tmp_path / "a.png")
    cluster.texsyn("watch", done, "--quiet")
    ended = os.stat(job_dir(cluster, done) / "state").st_mtime
    pause(cluster, True)
    held = submit(cluster, data, tmp_path / "b.png")
    assert listed(cluster)[held]["state"] == "held"
    wait_until("the finished job to be removed", lambda: not job_dir(cluster, done).exists())
    gone_at = time.time()
    assert gone_at >= ended + 2 - 0.05, f"removed {gone_at - ended:.2f} s after its end, with --keep-ended 2"
    p = cluster.texsyn("status", done, check=False)
    assert p.returncode == 1 and p.stderr == f"texsyn status: no job {done}\n", p.stderr
    assert done not in listed(cluster)
    assert re.search(rf"job {done} removed: it ended more than 2 s ago \(--keep-ended\)", cluster.server.read_log())
    # Queued longer than the keep time: held still, its files there.
    wait_until("the held job to outlast the keep time", lambda: time.time() > gone_at + 3, timeout=10)
    assert listed(cluster)[held]["state"] == "held" and job_dir(cluster, held).exists()
    pause(cluster, False)
    cluster.texsyn("watch", held, "--quiet")
    wait_until("the second job to be removed once it ended", lambda: held not in listed(cluster))
    assert not job_dir(cluster, held).exists()


@pytest.mark.sanitize
def test_keep_ended_counts_from_the_end_across_a_restart(data, cluster, tmp_path):
    """The end is the spool's (the state file's time), not the restart's: a
    job that ended an hour ago goes at once under --keep-ended 30m, one that
    just ended stays; --keep-ended 1h then keeps the rest."""
    cluster.start(1, 1)
    old = submit(cluster, data, tmp_path / "a.png")
    fresh = submit(cluster, data, tmp_path / "b.png")
    for job in (old, fresh):
        cluster.texsyn("watch", job, "--quiet")
    state = job_dir(cluster, old) / "state"
    hour_ago = time.time() - 3600
    os.utime(state, (hour_ago, hour_ago))
    cluster.server.stop()
    cluster.restart_server("--keep-ended", "30m")
    wait_until("the job that ended an hour ago to be removed", lambda: not job_dir(cluster, old).exists())
    rows = listed(cluster)
    assert old not in rows and rows[fresh]["state"] == "done", rows
    assert "removed: it ended more than 1800 s ago" in cluster.server.read_log()
    cluster.server.stop()
    cluster.restart_server("--keep-ended", "1h", log="server3.log")
    assert list(listed(cluster)) == [fresh] and job_dir(cluster, fresh).exists()


@pytest.mark.sanitize
def test_keep_ended_refuses_what_is_no_duration(tmp_path):
    for bad in ("5x", "0", "-3", "12hh", "", "forever"):
        p = run(BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool", "--keep-ended",
                bad, check=False, timeout=30)
        assert (p.returncode, p.stderr) == (2, f"texsyn-server: --keep-ended {bad}: need a duration above 0 such "
                                               "as 3600, 90s, 30m, 12h or 7d\n"), (bad, p.stderr)
    assert not (tmp_path / "spool").exists()
    help_text = run(BUILD / "texsyn-server", "--help").stdout
    assert "--keep-ended TIME" in help_text and "default: keep forever" in help_text


@pytest.mark.sanitize
def test_delete_ended_removes_every_ended_job_and_no_other(data, cluster, tmp_path):
    """delete --ended: the done and the canceled job go, with their files,
    and it says which; the held one stays. Again: nothing to delete."""
    cluster.start(1, 1, *MB)
    done = submit(cluster, data, tmp_path / "a.png")
    cluster.texsyn("watch", done, "--quiet")
    pause(cluster, True)
    canceled = submit(cluster, data, tmp_path / "b.png")
    cluster.texsyn("cancel", canceled)
    held = submit(cluster, data, tmp_path / "c.png")
    p = cluster.texsyn("delete", "--ended")
    assert p.stdout == f"deleted 2 ended jobs: {done} (done), {canceled} (canceled)\n", p.stdout
    assert list(listed(cluster)) == [held] and listed(cluster)[held]["state"] == "held"
    assert not job_dir(cluster, done).exists() and not job_dir(cluster, canceled).exists()
    assert job_dir(cluster, held).exists()
    assert cluster.texsyn("delete", "--ended").stdout == "no ended jobs to delete\n"
    for args, message in ((["delete", held, "--ended"], "delete takes a job id or --ended, not both"),
                          (["status", "--ended"], "--ended is an option of texsyn delete only")):
        p = cluster.texsyn(*args, check=False)
        assert (p.returncode, p.stderr) == (2, f"texsyn {args[0]}: {message}\n"), p.stderr
    p = cluster.texsyn("delete", check=False)
    assert p.returncode == 2 and p.stderr.startswith("texsyn delete: delete needs a job id (or --ended)\n")


@pytest.mark.sanitize
def test_status_shows_engine_owner_times_progress_and_output(data, cluster, tmp_path):
    """The listing: a header, then per job its id, state (held behind the
    paused queue), engine, owner (the client's USER@HOST), times, progress
    and the -o name; status ID the same in full."""
    cluster.start(1, 1, *MB)
    host = os.uname().nodename
    done = submit(cluster, data, tmp_path / "castle.png", env={"USER": "alice"})
    cluster.texsyn("watch", done, "--quiet")
    pause(cluster, True)
    held = submit(cluster, data, tmp_path / "later.png", env={"USER": "bob"})
    text = cluster.texsyn("status").stdout
    assert text.splitlines()[0].split() == STATUS_HEADER, text
    rows = {r["id"]: r for r in jobs_listed(text)}
    clock = re.compile(r"\d\d:\d\d:\d\d|\d{4}-\d\d-\d\d")  # today's clock time, else the date
    d, h = rows[done], rows[held]
    assert (d["state"], d["engine"], d["owner"], d["progress"], d["output"]) == \
        ("done", "mrf", f"alice@{host}", "100.0%", "castle.png"), d
    assert all(clock.fullmatch(d[k]) for k in ("submitted", "started", "ended")), d
    assert (h["state"], h["owner"], h["started"], h["ended"], h["progress"], h["output"]) == \
        ("held", f"bob@{host}", "-", "-", "-", "later.png"), h
    assert clock.fullmatch(h["submitted"]) and h["note"].startswith("the queue is paused"), h
    lines = cluster.texsyn("status", held).stdout.splitlines()
    assert lines[0].split()[:2] == [held, "held"], lines
    fields = dict(re.fullmatch(r"  (\w+) +(.*)", line).groups() for line in lines[1:])
    assert (fields["engine"], fields["owner"], fields["output"], fields["started"], fields["ended"]) == \
        ("mrf", f"bob@{host}", "later.png", "-", "-"), fields
    when = r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d \S+ \([\d.]+s ago\)"
    assert re.fullmatch(when, fields["submitted"]), fields
    full = dict(re.fullmatch(r"  (\w+) +(.*)", line).groups() for line in
                cluster.texsyn("status", done).stdout.splitlines()[1:])
    assert re.fullmatch(when + r", ran [\d.]+s", full["ended"]) and full["progress"] == "100.0%", full
    # A client following it says it is held, then that it runs once resumed.
    watch = subprocess.Popen([str(BUILD / "texsyn"), "watch", held, "--server", cluster.server.addr],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert watch.stderr.readline() == f"texsyn watch: job {held} held: the coordinator's queue is paused\n"
    pause(cluster, False)
    out, err = watch.communicate(timeout=120)
    assert watch.returncode == 0 and out == f"{held}      done\n", (out, err)
    assert f"texsyn watch: job {held} level 1 of 2" in err, err
    assert listed(cluster)[held]["state"] == "done"


@pytest.mark.sanitize
def test_workers_shows_names_draining_and_dead(data, cluster, tmp_path):
    """texsyn workers: a header, each worker's --name; a draining worker
    at share 0; a killed one listed as dead with when it was dropped,
    until a worker of its name joins again."""
    for _ in range(2):
        cluster.worker(1, "--modbus", "0", "--modbus-control", "--modbus-allow", "127.0.0.1")
    cluster.start(0, 1, "--heartbeat", "0.5", "--calibrate-ms", "50")
    joined = cluster.worker(1, "--join", cluster.server.addr, "--name", "joiner")
    cluster.wait_ready(3)
    text = cluster.texsyn("workers").stdout
    assert text.splitlines()[0].split() == ["NAME", "ADDRESS", "THREADS", "SIMD", "CALIBRATED", "RATE", "SHARE",
                                            "STATE", "BATCHES"], text
    assert sorted(w["name"] for w in workers_listed(text)) == ["joiner", "w0", "w1"]
    cluster.texsyn("synth", "--ref", ref_of(data), "-o", tmp_path / "x.png", "--size", "96x64", "--quiet")
    assert all(w["share"] > 0 for w in cluster.pool()), cluster.pool()
    run(BUILD / "texsyn", "modbus", cluster.workers[0].modbus, "--set", "drain=1")
    wait_until("w0 to drain", lambda: {w["name"]: w["state"] for w in cluster.pool()}["w0"] == "draining")
    assert {w["name"]: w["share"] for w in cluster.pool()}["w0"] == 0
    cluster.workers[1].proc.kill()
    cluster.workers[1].proc.wait()

    def by_name():
        return {w["name"]: w for w in cluster.pool(dead=True)}
    wait_until("w1 to be listed dead", lambda: by_name()["w1"]["state"] == "dead")
    dead = by_name()["w1"]
    assert dead["share"] == 0 and dead["addr"] == cluster.workers[1].addr, dead
    assert re.fullmatch(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d \S+ \([\d.]+s ago\)", dead["dropped"]), dead
    assert [w["name"] for w in cluster.pool()].count("w1") == 0  # not in the pool itself
    # The joined worker dies, and a worker of its name joins: one joiner, active.
    joined.proc.kill()
    joined.proc.wait()
    wait_until("joiner to be listed dead", lambda: by_name()["joiner"]["state"] == "dead")
    cluster.worker(1, "--join", cluster.server.addr, "--name", "joiner")
    wait_until("joiner back", lambda: [w for w in cluster.pool(dead=True) if w["name"] == "joiner"] and
               all(w["state"] == "active" for w in cluster.pool(dead=True) if w["name"] == "joiner"))
    assert [w["name"] for w in cluster.pool(dead=True)].count("joiner") == 1
    assert by_name()["w1"]["state"] == "dead"
