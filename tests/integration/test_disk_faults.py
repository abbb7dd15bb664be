"""An unwritable spool: EACCES, EROFS, EIO and ENOSPC injected into the
coordinator's calls that change its spool (tests/preload/spool_fault.c).
The coordinator neither crashes nor aborts. What the failed call was for
is refused or failed with a message naming the file and the system's
reason: a start-up, a submission (the client is told), a job's result or
state (the job fails with it), a deletion. A checkpoint, or what is left
of a deleted job, is logged and the job goes on. The other jobs keep
being served with the embedded run's bytes, and once the fault clears a
new job runs to its end.

In the suite: a spool that turns read-only and heals, and one point per
errno. `make test-faults` (marker long): each errno at every point of the
lifecycle of spool_points.py, a table per errno."""
import errno
import os
import re

import pytest

from spool_points import Client, counted_lifecycle, listing, pick, read_points, start_server


def tolerated(point):
    """Whether the point's failure costs nothing a client asked for: it is
    logged, and the job goes on (a checkpoint) or the deletion stands (the
    files of a job renamed away)."""
    return bool(re.search(r"/checkpoint(\.tmp(-\d+)?)?$", point.path)) or \
        (point.call in ("unlink", "rmdir") and ".deleted" in point.path)


def subject(points, point):
    """The point a failure is about: for the fsync of a directory right
    after a rename or mkdir in it, that call, which it makes durable."""
    prev = next((p for p in points if p.n == point.n - 1), None)
    if point.call == "fsync" and prev and prev.call in ("rename", "mkdir") and \
            os.path.dirname(prev.path) == point.path:
        return prev
    return point


def named(point):
    """What a message about the point names: its file (a temporary's
    suffix dropped), the directory an fsync was of, or the job directory
    a deletion renames."""
    return re.sub(r"\.tmp(-\d+)*$|(?<=\d)\.deleted$", "", point.path)


def says(line, names, text):
    """Whether a message names one of names and gives the system's reason."""
    return text in line and any(n in line for n in names)


def new_job_runs(server, tmp, data, expected):
    """After the fault: a new job to its end, with the embedded bytes."""
    (tmp / "after").mkdir()
    client = Client(server, tmp / "after", data)
    for what in ("submit", "watch", "fetch"):
        assert client.step(what, "A", expected), client.errors


def fault_at(k, name, points, count_spool, data, expected, tmp_path):
    """The lifecycle with errno `name` at point k; the table's row."""
    tmp = tmp_path / f"{name}-{k}"
    tmp.mkdir()
    spool = tmp / "spool"
    text = os.strerror(getattr(errno, name))
    server = start_server(tmp, spool, "server1.log", tmp / "points1.log", fault=name, at=k)
    client = Client(server, tmp, data) if server else None
    if client:
        client.every_step(expected)
    hit = [p for p in read_points(tmp / "points1.log") if p.acted]
    want = points[k - 1]
    assert [(p.n, p.call, p.where(spool)) for p in hit] == [(k, want.call, want.where(count_spool))], \
        f"{name} at {k}: the run diverged from the count"
    point = subject(read_points(tmp / "points1.log"), hit[0])
    # A message names the file, or the directory synced (a job's results),
    # or for the files of a deleted job, their directory.
    names = {named(point), named(hit[0])} | ({os.path.dirname(point.path)} if tolerated(point) else set())
    if server is None:
        log = (tmp / "server1.log").read_text()
        assert any(says(line, names, text) for line in log.splitlines() if line.startswith("texsyn-server: ")), log
        outcome = "start refused"
        server = start_server(tmp, spool, "server2.log", tmp / "points2.log")
        assert server is not None, "the coordinator did not start once the fault cleared"
        client = Client(server, tmp, data)
        assert client.lifecycle(expected), client.errors
    else:
        assert server.alive(), server.read_log()
        rows = listing(server)
        failed = {job: text for job, (state, text) in rows.items() if state != "done"}
        log = server.read_log()
        if tolerated(point):
            assert client.errors == [] and failed == {}, (client.errors, failed)
            assert any(says(line, names, text) for line in log.splitlines()), log
            outcome = "logged, the job goes on" if "checkpoint" in point.path else "logged, the deletion stands"
        else:
            told = [e for _, e in client.errors] + list(failed.values())
            assert any(says(m, names, text) for m in told), (told, log)
            assert all(says(t, names, text) for t in failed.values()), failed
            steps = [step for step, _ in client.errors]
            outcome = "job failed" if any(s.startswith("watch") for s in steps) else f"{steps[0].split()[0]} refused"
        # One job hit at most; the other served in full (Client.step checks
        # the bytes).
        hit_jobs = {step.split()[1] for step, _ in client.errors}
        assert len(hit_jobs) <= 1 and len(client.served | hit_jobs) == 2, (client.served, client.errors)
    new_job_runs(server, tmp, data, expected)
    left = sorted(os.listdir(spool / "jobs"))
    if any(n.endswith(".deleted") for n in left):  # logged: a restart tries again
        server.stop()
        server = start_server(tmp, spool, "server3.log", tmp / "points3.log")
        left = sorted(os.listdir(spool / "jobs"))
    assert left == sorted(listing(server)), f"{name} at {k}: SPOOL/jobs holds {left}"
    server.stop()
    return (k, hit[0].call, hit[0].where(spool), outcome)


@pytest.fixture(scope="module")
def counted(texsyn, data, tmp_path_factory):
    return counted_lifecycle(texsyn, data, tmp_path_factory.mktemp("count"))


def test_a_spool_turned_read_only_refuses_and_heals(data, counted, tmp_path):
    """EROFS at every call while the disk is "read-only": a submission and a
    deletion are refused with the file and the reason, a finished job is
    still served; healed, the same requests go through. The refused
    submission's id is not given again."""
    expected, _, _ = counted
    spool, read_only = tmp_path / "spool", tmp_path / "read-only"
    server = start_server(tmp_path, spool, "server.log", tmp_path / "points.log", fault="EROFS", while_file=read_only)
    client = Client(server, tmp_path, data)
    assert all(client.step(what, "A", expected) for what in ("submit", "watch")), client.errors
    read_only.touch()
    assert not client.step("submit", "B", expected)
    assert not client.step("delete", "A", expected)
    assert client.step("fetch", "A", expected)
    assert client.errors == [
        ("submit B", f"texsyn synth: cannot write {spool}/last-id: Read-only file system"),
        ("delete A", f"texsyn delete: cannot remove {spool}/jobs/1: Read-only file system")], client.errors
    assert listing(server) == {"1": ("done", "")}
    read_only.unlink()
    assert all(client.step(what, name, expected) for what, name in
               [("submit", "B"), ("watch", "B"), ("fetch", "B"), ("delete", "A")]), client.errors
    assert client.ids == {"A": "1", "B": "3"}
    assert listing(server) == {"3": ("done", "")}
    assert sorted(os.listdir(spool / "jobs")) == ["3"]


def test_one_fault_per_errno(data, counted, tmp_path):
    """A submission refused (EACCES at job.spec), a job failed (ENOSPC at
    its report, EIO at its state) and a deletion refused (EROFS)."""
    expected, spool, points = counted
    cases = [("EACCES", pick(points, spool, "open", r"jobs/1/job\.spec\.tmp-PID"), "submit refused"),
             ("ENOSPC", pick(points, spool, "fflush", r"jobs/1/report\.json\.tmp-PID"), "job failed"),
             ("EIO", pick(points, spool, "rename", r"jobs/2/state"), "job failed"),
             ("EROFS", pick(points, spool, "rename", r"jobs/1\.deleted"), "delete refused")]
    for name, k, outcome in cases:
        assert fault_at(k, name, points, spool, data, expected, tmp_path)[3] == outcome, (name, k)


@pytest.mark.long
@pytest.mark.parametrize("name", ["EIO", "EACCES", "EROFS", "ENOSPC"])
def test_every_point_of_the_spool_fails(name, data, counted, tmp_path, capsys):
    expected, spool, points = counted
    rows = [fault_at(p.n, name, points, spool, data, expected, tmp_path) for p in points]
    width = max(len(r[2]) for r in rows)
    lines = [f"{'point':>5}  {'call':<7} {'path':<{width}}  outcome"]
    lines += [f"{k:>5}  {call:<7} {where:<{width}}  {outcome}" for k, call, where, outcome in rows]
    counts = {}
    for row in rows:
        counts[row[3]] = counts.get(row[3], 0) + 1
    with capsys.disabled():
        print(f"\n{name} at each of {len(rows)} points ({counts}):\n" + "\n".join(lines))
