"""Limits of the coordinator: unfinished jobs per client and the spool's
disk use. A submission past a limit is refused with a message that says
which limit and what to do, other clients' jobs carry on, and deleting
finished jobs gives the space back (their ids are never reused)."""
import subprocess
import time

from conftest import BUILD, Daemon, run, synth

SMALL = ["--size", "96x64", "--levels", "3"]
LONG = ["--size", "768x768"]  # seconds on a lone coordinator: stays unfinished


def ref_of(data):
    return data / "textures" / "brick.png"


def as_client(cluster, user, *args, check=True):
    """`texsyn ARGS --server ...` as another user: the coordinator tells
    clients apart by the user@host they identify with."""
    return run(BUILD / "texsyn", *args, "--server", cluster.server.addr, env={"USER": user}, check=check)


def submit(cluster, user, data, out, *job):
    p = as_client(cluster, user, "synth", "--ref", ref_of(data), "-o", out, *job, "--detach", check=False)
    return p.returncode, p.stdout.strip(), p.stderr


def test_per_client_job_limit_refuses_only_that_client(texsyn, data, cluster, tmp_path):
    cluster.start(0, 1, "--jobs", "1", "--max-client-jobs", "2")
    ids = []
    for i in range(2):
        code, job, err = submit(cluster, "alice", data, tmp_path / "a.png", *LONG, "--seed", str(i + 1))
        assert code == 0, err
        ids.append(job)
    code, _, err = submit(cluster, "alice", data, tmp_path / "a.png", *LONG)
    assert code != 0
    assert "already has 2 unfinished jobs" in err and "--max-client-jobs" in err, err
    code, bob, err = submit(cluster, "bob", data, tmp_path / "b.png", *SMALL)
    assert code == 0, err
    # A running job cannot be deleted; canceling it frees alice's slot.
    busy = as_client(cluster, "alice", "delete", ids[0], check=False)
    assert busy.returncode == 1 and "cancel it first" in busy.stderr, busy.stderr
    as_client(cluster, "alice", "cancel", ids[0])
    code, again, err = submit(cluster, "alice", data, tmp_path / "a.png", *SMALL)
    assert code == 0, err
    as_client(cluster, "alice", "cancel", ids[1])  # still queued: never starts
    assert " canceled" in as_client(cluster, "alice", "status", ids[1]).stdout
    for job in (bob, again):
        as_client(cluster, "bob", "watch", job, "--quiet")
    want = tmp_path / "want.png"
    synth(texsyn, ref_of(data), want, (96, 64), "--levels", "3")
    as_client(cluster, "bob", "fetch", bob, "-o", tmp_path / "bob.png")
    assert (tmp_path / "bob.png").read_bytes() == want.read_bytes()
    assert cluster.server.alive()


def test_spool_limit_refuses_until_jobs_are_deleted(texsyn, data, cluster, tmp_path):
    cluster.start(0, 1, "--max-spool", "600K")
    done = []
    for i in range(10):
        code, job, err = submit(cluster, "carol", data, tmp_path / "c.png", *SMALL, "--seed", str(i + 1))
        if code != 0:
            break
        as_client(cluster, "carol", "watch", job, "--quiet")
        done.append(job)
    assert code != 0, "ten jobs fit a 600 KiB spool?"
    assert "spool is full" in err and "--max-spool" in err and "texsyn delete" in err, err
    assert 1 <= len(done) < 10
    as_client(cluster, "carol", "delete", done[0])
    status = as_client(cluster, "carol", "status").stdout
    assert not any(line.split()[0] == done[0] for line in status.splitlines()), status
    gone = as_client(cluster, "carol", "fetch", done[0], "-o", tmp_path / "x.png", check=False)
    assert gone.returncode == 1 and f"no job {done[0]}" in gone.stderr
    code, job, err = submit(cluster, "carol", data, tmp_path / "c.png", *SMALL)
    assert code == 0, err
    as_client(cluster, "carol", "watch", job, "--quiet")
    missing = as_client(cluster, "carol", "delete", "9999", check=False)
    assert missing.returncode == 1 and "no job 9999" in missing.stderr


def test_deleted_ids_are_not_reused_after_a_restart(data, cluster, tmp_path):
    cluster.start(0, 1)
    code, job, err = submit(cluster, "dave", data, tmp_path / "d.png", *SMALL)
    assert code == 0, err
    as_client(cluster, "dave", "watch", job, "--quiet")
    as_client(cluster, "dave", "delete", job)
    cluster.server.stop()
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", cluster.tmp / "spool"],
                            cluster.tmp / "server2.log")
    code, again, err = submit(cluster, "dave", data, tmp_path / "d.png", *SMALL)
    assert code == 0, err
    assert int(again) > int(job)
