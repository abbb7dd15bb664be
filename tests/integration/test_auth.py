"""Authentication: with --secret-file every client and worker proves the
shared secret (and the daemon proves it back); a wrong or missing secret is
refused with a message the user can act on and a log line naming the peer,
and the daemon goes on serving everyone else. Without a secret a daemon
admits loopback peers only (protected mode)."""
import os
import subprocess
import time

import pytest

from conftest import BUILD, Daemon, run, synth

SIZE = ("96x64", "--levels", "3")


def secret(tmp_path, name, mode=0o600, text=None):
    path = tmp_path / name
    path.write_text(text if text is not None else os.urandom(24).hex() + "\n")
    path.chmod(mode)
    return path


def ref_of(data):
    return data / "textures" / "brick.png"


def embedded(texsyn, data, tmp_path):
    out = tmp_path / "embedded.png"
    synth(texsyn, ref_of(data), out, (96, 64), "--levels", "3")
    return out.read_bytes()


def remote(addr, data, out, *extra, env=None, check=True):
    return run(BUILD / "texsyn", "synth", "--server", addr, "--ref", ref_of(data), "-o", out, "--size", *SIZE,
               "--quiet", *extra, env=env, check=check)


def start_server(cluster, *args, listen="127.0.0.1:0", workers=()):
    argv = [BUILD / "texsyn-server", "--listen", listen, "--spool", cluster.tmp / "spool", *args]
    if workers:
        argv += ["--workers", ",".join(workers)]
    cluster.server = Daemon(argv, cluster.tmp / "server.log")
    return cluster.server


def wait_for(what, predicate, timeout=15):
    deadline = time.time() + timeout
    while time.time() < deadline:
        if predicate():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.mark.sanitize
def test_same_secret_everywhere_matches_embedded(texsyn, data, cluster, tmp_path, monkeypatch):
    want = embedded(texsyn, data, tmp_path)
    key = secret(tmp_path, "secret")
    monkeypatch.setenv("TEXSYN_SECRET_FILE", str(key))  # the fixture's `texsyn workers` calls
    listening = cluster.worker(1, "--secret-file", key)
    start_server(cluster, "--secret-file", key, workers=[listening.addr])
    cluster.worker(1, "--secret-file", key, "--join", cluster.server.addr)
    cluster.wait_ready(2)
    out = tmp_path / "remote.png"
    # The option, not only the environment, carries the secret.
    remote(cluster.server.addr, data, out, "--secret-file", key, env={"TEXSYN_SECRET_FILE": ""})
    assert out.read_bytes() == want
    assert all(w["batches"] > 0 for w in cluster.pool())
    assert "refused" not in cluster.server.read_log()


@pytest.mark.sanitize
def test_client_with_wrong_or_no_secret_is_refused(data, cluster, tmp_path, monkeypatch):
    key = secret(tmp_path, "secret")
    wrong = secret(tmp_path, "wrong")
    start_server(cluster, "--secret-file", key)
    addr = cluster.server.addr
    p = remote(addr, data, tmp_path / "a.png", "--secret-file", wrong, check=False)
    assert p.returncode == 1 and "authentication failed: wrong secret" in p.stderr, p.stderr
    p = remote(addr, data, tmp_path / "b.png", env={"TEXSYN_SECRET_FILE": wrong}, check=False)
    assert p.returncode == 1 and "wrong secret" in p.stderr, p.stderr
    p = remote(addr, data, tmp_path / "c.png", env={"TEXSYN_SECRET_FILE": ""}, check=False)
    assert p.returncode == 1, p.stderr
    assert "this server requires authentication: pass --secret-file" in p.stderr, p.stderr
    p = run(BUILD / "texsyn", "workers", "--server", addr, env={"TEXSYN_SECRET_FILE": ""}, check=False)
    assert p.returncode == 1 and "requires authentication" in p.stderr, p.stderr
    assert not (tmp_path / "a.png").exists() and not (tmp_path / "c.png").exists()
    log = cluster.server.read_log()
    assert log.count("refused 127.0.0.1:") == 4, log
    assert "wrong secret" in log and "requires authentication" in log
    # Still serving, and a correct client gets its job done.
    assert cluster.server.alive()
    monkeypatch.setenv("TEXSYN_SECRET_FILE", str(key))
    remote(addr, data, tmp_path / "ok.png")
    assert (tmp_path / "ok.png").stat().st_size > 0


def test_client_with_a_secret_refuses_a_server_without(data, cluster, tmp_path):
    start_server(cluster)
    p = remote(cluster.server.addr, data, tmp_path / "x.png", "--secret-file", secret(tmp_path, "k"), check=False)
    assert p.returncode == 1 and "no --secret-file" in p.stderr, p.stderr
    assert "refused 127.0.0.1:" in cluster.server.read_log()


def test_worker_with_wrong_secret_is_refused_listen_and_join(texsyn, data, cluster, tmp_path, monkeypatch):
    want = embedded(texsyn, data, tmp_path)
    key = secret(tmp_path, "secret")
    wrong = secret(tmp_path, "wrong")
    monkeypatch.setenv("TEXSYN_SECRET_FILE", str(key))
    good = cluster.worker(1, "--secret-file", key)
    bad_listen = cluster.worker(1, "--secret-file", wrong)
    no_secret = cluster.worker(1)
    start_server(cluster, "--secret-file", key, workers=[good.addr, bad_listen.addr, no_secret.addr])
    bad_join = cluster.worker(1, "--secret-file", wrong, "--join", cluster.server.addr)
    cluster.wait_ready(1)
    # Each refusal by its own line: the joiner's retries alone can make
    # three "authentication failed" before the coordinator has dialled the
    # worker without a secret.
    wait_for("the refusals in the logs", lambda: "join" in bad_join.read_log()
             and "refused" in bad_listen.read_log()
             and f"worker {bad_listen.addr}: " in cluster.server.read_log()
             and f"worker {no_secret.addr}: " in cluster.server.read_log())
    log = cluster.server.read_log()
    assert f"worker {bad_listen.addr}: {bad_listen.addr}: authentication failed: wrong secret" in log, log
    assert f"worker {no_secret.addr}: {no_secret.addr}: authentication failed: this worker has no --secret-file" \
        in log, log
    assert "refused 127.0.0.1:" in log
    assert "wrong secret" in bad_listen.read_log()
    assert f"join {cluster.server.addr} refused" in bad_join.read_log()
    assert "refused" in no_secret.read_log() and "no --secret-file" in no_secret.read_log()
    pool = cluster.pool()
    assert [w["addr"] for w in pool] == [good.addr] and pool[0]["state"] == "active", pool
    out = tmp_path / "remote.png"
    remote(cluster.server.addr, data, out)
    assert out.read_bytes() == want
    assert [w["addr"] for w in cluster.pool()] == [good.addr]


@pytest.mark.sanitize
@pytest.mark.parametrize("mode,text,why", [(0o644, None, "chmod 600"), (0o640, None, "chmod 600"),
                                           (0o600, "", "empty"), (0o600, "x" * 5000, "more than")])
def test_bad_secret_file_stops_daemons_and_client(data, tmp_path, mode, text, why):
    bad = secret(tmp_path, "secret", mode, text)
    for exe, args in (("texsyn-server", ["--listen", "127.0.0.1:0", "--spool", tmp_path / "spool"]),
                      ("texsyn-worker", ["--listen", "127.0.0.1:0"])):
        p = subprocess.run([str(BUILD / exe), *map(str, args), "--secret-file", str(bad)], capture_output=True,
                           text=True, timeout=30)
        assert p.returncode == 2 and why in p.stderr and str(bad) in p.stderr, (exe, p.stderr)
        assert "listening" not in p.stdout
    p = remote("127.0.0.1:9", data, tmp_path / "x.png", "--secret-file", bad, check=False)
    assert p.returncode == 1 and why in p.stderr, p.stderr


def non_loopback_ipv4():
    """An address of this machine other than loopback, or None."""
    try:
        out = subprocess.run(["hostname", "-I"], capture_output=True, text=True, timeout=10).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    for a in out.split():
        if "." in a and not a.startswith("127."):
            return a
    return None


def test_protected_mode_admits_loopback_only(data, cluster, tmp_path):
    ip = non_loopback_ipv4()
    if ip is None:
        pytest.skip("this machine has no non-loopback IPv4 address")
    server = start_server(cluster, listen="0.0.0.0:0")
    assert "WARNING" in server.read_log() and "protected mode" in server.read_log()
    p = run(BUILD / "texsyn", "workers", "--server", f"{ip}:{server.port}", env={"TEXSYN_SECRET_FILE": ""},
            check=False)
    assert p.returncode == 1 and "protected mode: no --secret-file is configured" in p.stderr, p.stderr
    assert f"refused {ip}:" in server.read_log()
    assert run(BUILD / "texsyn", "workers", "--server", f"127.0.0.1:{server.port}").returncode == 0
    # A worker in protected mode refuses a coordinator that comes from elsewhere.
    w = cluster.worker(1, "--listen", "0.0.0.0:0")
    cluster.server.stop()
    start_server(cluster, workers=[f"{ip}:{w.port}"])
    wait_for("the worker's refusal", lambda: "protected mode" in w.read_log())
    assert cluster.pool() == []


def ready_at(addr):
    """Workers ready on the coordinator at addr."""
    return run(BUILD / "texsyn", "workers", "--server", addr).stdout.count(" active ")


def test_secret_lifts_protected_mode(data, cluster, tmp_path, monkeypatch):
    ip = non_loopback_ipv4()
    if ip is None:
        pytest.skip("this machine has no non-loopback IPv4 address")
    key = secret(tmp_path, "secret")
    monkeypatch.setenv("TEXSYN_SECRET_FILE", str(key))
    w = cluster.worker(1, "--listen", "0.0.0.0:0", "--secret-file", key)
    server = start_server(cluster, "--secret-file", key, listen="0.0.0.0:0", workers=[f"{ip}:{w.port}"])
    assert "WARNING" not in server.read_log()
    addr = f"{ip}:{server.port}"
    wait_for("the worker", lambda: ready_at(addr) == 1)
    remote(addr, data, tmp_path / "x.png")
    assert "refused" not in server.read_log() + w.read_log()
