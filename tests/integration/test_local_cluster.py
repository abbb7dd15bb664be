"""deploy/local-cluster.sh: start a coordinator and workers, run a job
through $TEXSYN_SERVER, see the pool in `status`, stop everything."""
import os
import subprocess

from conftest import BUILD, REPO, run, synth

SCRIPT = REPO / "deploy" / "local-cluster.sh"


def script(env, *args):
    p = subprocess.run(["bash", str(SCRIPT), *args], capture_output=True, text=True, env=env, timeout=60)
    assert p.returncode == 0, f"local-cluster.sh {' '.join(args)} failed:\n{p.stdout}\n{p.stderr}"
    return p.stdout


def pids(run_dir):
    return [int(line.split()[0]) for line in (run_dir / "pids").read_text().splitlines()]


def alive(pid):
    """Running, not a zombie (a container's init may be slow to reap)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_local_cluster_start_job_status_stop(texsyn, data, tmp_path):
    env = dict(os.environ, TEXSYN_RUN=str(tmp_path / "run"), TEXSYN_BUILD=str(BUILD))
    out = script(env, "start", "2", "--threads", "1")
    addr = out.strip().splitlines()[-1].split("=", 1)[1]
    started = pids(tmp_path / "run")
    try:
        assert len(started) == 3 and all(alive(p) for p in started)
        ref = data / "textures" / "grass.png"
        want = tmp_path / "embedded.png"
        synth(texsyn, ref, want, (96, 64), "--levels", "3")
        got = tmp_path / "cluster.png"
        run(texsyn, "synth", "--ref", ref, "-o", got, "--size", "96x64", "--levels", "3", "--quiet",
            env={"TEXSYN_SERVER": addr})
        assert got.read_bytes() == want.read_bytes()
        status = script(env, "status")
        assert status.count(" active ") == 2 and "DEAD" not in status
    finally:
        script(env, "stop")
    assert not any(alive(p) for p in started)
    assert "nothing running" in script(env, "stop")
