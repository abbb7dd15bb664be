"""Crash-point enumeration: the coordinator killed at each call that
changes its spool, one at a time, and started again on it.

The lifecycle of spool_points.py (job A submitted with a report, run,
fetched; job B submitted and run; A deleted; B fetched) runs once under
tests/preload/spool_fault.c to number the spool's points. Its trace must
keep the durability order: a renamed file fsynced after its last write
and before its rename, and every rename and mkdir followed by an fsync of
its directory before the next commit (a job.spec, a state, a deletion)
and before the end. Then, for a point k, the lifecycle runs again with the
coordinator killed (SIGKILL) at k, the call not made, and a coordinator
started on the same spool must show: every job whose submission was
acknowledged listed, unless its deletion was acknowledged; every listed
job done with the embedded run's bytes (and A's report); each job
completed once (its state written by one coordinator only: a job done
before the kill does not run again); nothing in SPOOL/jobs but the listed
jobs; a new job numbered past every id that ever had a directory.

Every point runs in `make test-faults` (marker long), which prints the
table (point, call, path, outcome); the suite runs the trace check and
three points: B's job.spec, A's state and a file of A's deletion."""
import os
import re
import signal

import pytest

from conftest import BUILD, run
from spool_points import JOBS, Client, counted_lifecycle, job_of, listing, pick, read_points, ref_of, start_server

COMMITS = re.compile(r"(^|/)(job\.spec|state)$|\.deleted$")


def durability_faults(points, spool):
    """Where the trace breaks the durability order, as sentences."""
    faults = []
    for i, p in enumerate(points):
        parent = os.path.dirname(p.path)
        if p.call == "rename" and not p.path.endswith(".deleted"):
            tmp = next((q for q in reversed(points[:i]) if q.path.startswith(p.path + ".tmp")), None)
            if tmp is None or tmp.call != "fsync":
                faults.append(f"{p.where(spool)} renamed without an fsync after its last write "
                              f"(last: {tmp.call if tmp else 'none'})")
        if p.call in ("rename", "mkdir") and p.path != str(spool):
            for q in points[i + 1:]:
                if q.call == "fsync" and q.path == parent:
                    break
                if q.call == "rename" and COMMITS.search(q.path) and q.path != p.path:
                    faults.append(f"{p.call} {p.where(spool)} not synced in its directory before "
                                  f"{q.where(spool)} was committed")
                    break
            else:
                faults.append(f"{p.call} {p.where(spool)} never synced in its directory")
    return faults


def completed(points, spool):
    """The jobs whose state a coordinator wrote (the rename made)."""
    return {job_of(p, spool) for p in points if p.call == "rename" and p.path.endswith("/state") and not p.acted}


def crash_at(k, count_points, count_spool, data, expected, tmp_path):
    """The lifecycle with the coordinator killed at point k, then a
    restart's view checked. Returns the table's row."""
    tmp = tmp_path / f"p{k}"
    tmp.mkdir()
    spool = tmp / "spool"
    first = start_server(tmp, spool, "server1.log", tmp / "points1.log", fault="kill", at=k)
    client = None
    if first is not None:
        first.expect_signal(signal.SIGKILL)
        client = Client(first, tmp, data)
        assert not client.lifecycle(expected), f"point {k}: the lifecycle ended without reaching it"
        first.proc.wait(timeout=60)
    before = read_points(tmp / "points1.log")
    killed = before[-1]
    want = count_points[k - 1]
    assert (killed.n, killed.call, killed.acted, killed.where(spool)) == \
        (k, want.call, "kill", want.where(count_spool)), f"point {k}: the run diverged from the count: {killed}"
    done_before = completed(before, spool)

    second = start_server(tmp, spool, "server2.log", tmp / "points2.log")
    assert second is not None, (tmp / "server2.log").read_text()
    rows = listing(second)
    acked = client.ids if client else {}
    asked_deleted = client.asked_deleted if client else set()
    names = {str(i + 1): name for i, name in enumerate(JOBS)}  # ids in submission order
    for name, job in acked.items():
        if client and name in client.deleted:
            assert job not in rows, f"point {k}: job {name} came back after its deletion was acknowledged"
        elif name not in asked_deleted:
            assert job in rows, f"point {k}: job {name} ({job}) was acknowledged and is lost:\n{rows}"
    for job in sorted(rows):
        name = names[job]
        w = run(BUILD / "texsyn", "watch", job, "--quiet", "--server", second.addr, check=False, timeout=120)
        assert w.returncode == 0, f"point {k}: job {name}: {w.stderr}{second.read_log()}"
        out = tmp / f"after-{name}.png"
        extra = ["--report", tmp / f"after-{name}.json"] if name == "A" else []
        run(BUILD / "texsyn", "fetch", job, "-o", out, *extra, "--server", second.addr)
        assert out.read_bytes() == expected[name], f"point {k}: job {name} differs from the embedded run"
    done_after = completed(read_points(tmp / "points2.log"), spool)
    for job in rows:
        assert (job in done_before) + (job in done_after) == 1, \
            f"point {k}: job {names[job]} completed {'twice' if job in done_before else 'never'}"
    outcome = []
    for job, name in names.items():
        if job in rows:
            outcome.append(f"{name} {'rerun' if job in done_after else 'done'}")
        elif name in asked_deleted:
            outcome.append(f"{name} deleted{'' if client and name in client.deleted else ' (unacked)'}")
        elif any(job_of(p, spool) == job for p in before):
            outcome.append(f"{name} cut short, removed")
    left = sorted(os.listdir(spool / "jobs"))
    assert left == sorted(rows), f"point {k}: SPOOL/jobs holds {left}, the listing {sorted(rows)}"
    made = [int(job_of(p, spool)) for p in before if p.call == "mkdir" and job_of(p, spool) and not p.acted]
    new = run(BUILD / "texsyn", "synth", "--ref", ref_of(data), "-o", tmp / "new.png", "--size", "64x48",
              "--levels", "3", "--detach", "--server", second.addr).stdout.split()[-1]
    assert int(new) > max(made, default=0), f"point {k}: id {new} given again"
    second.stop()
    return (k, killed.call, killed.where(spool), ", ".join(outcome) or "no job submitted")


@pytest.fixture(scope="module")
def counted(texsyn, data, tmp_path_factory):
    return counted_lifecycle(texsyn, data, tmp_path_factory.mktemp("count"))


def test_the_lifecycle_keeps_the_durability_order(counted):
    _, spool, points = counted
    assert durability_faults(points, spool) == []
    calls = {p.call for p in points}
    assert {"open", "write", "fflush", "fsync", "rename", "mkdir", "unlink", "rmdir"} <= calls, calls


def test_killed_at_a_commit_the_restart_loses_and_repeats_nothing(data, counted, tmp_path):
    expected, spool, points = counted
    chosen = [pick(points, spool, "rename", r"jobs/2/job\.spec"), pick(points, spool, "rename", r"jobs/1/state"),
              pick(points, spool, "unlink", r"jobs/1(\.deleted)?/out\.png")]
    for k in chosen:
        crash_at(k, points, spool, data, expected, tmp_path)


@pytest.mark.long
def test_killed_at_every_point_of_the_spool(data, counted, tmp_path, capsys):
    expected, spool, points = counted
    rows = [crash_at(p.n, points, spool, data, expected, tmp_path) for p in points]
    width = max(len(r[2]) for r in rows)
    lines = [f"{'point':>5}  {'call':<7} {'path':<{width}}  outcome"]
    lines += [f"{k:>5}  {call:<7} {where:<{width}}  {outcome}" for k, call, where, outcome in rows]
    with capsys.disabled():
        print(f"\n{len(rows)} crash points, every acknowledged job kept, none run twice:\n" + "\n".join(lines))
