"""texsyn video on a pool of 3 workers, one of them killed while a chain's
frame is being stylized: the surviving workers take its slices and every
frame is the embedded run's bytes (issue 27, point 3). The shot is cut from
aero1.jpg by bench/video_shot.py; the key is its middle frame plus blurred
noise, so two chains (backward and forward) run side by side."""
import subprocess

from conftest import BUILD, REPO, run
from pnm import oiiotool

FRAMES = 8
KEY = 4


def make_shot(data, d):
    subprocess.run(["/usr/bin/python3", REPO / "bench" / "video_shot.py", d / "in_%04d.png", "--frames", str(FRAMES),
                    "--size", "96x72", "--source", data / "aerial" / "aero1.jpg"], check=True, capture_output=True,
                   timeout=120)
    oiiotool("--pattern", "noise:type=uniform:min=-0.5:max=0.5:seed=3", "96x72", "3", "--blur", "3x3",
             d / f"in_{KEY:04d}.png", "--add", "-d", "uint8", "-o", d / "key.png")


def video_args(d, out):
    return ["video", "--input", d / "in_%04d.png", "--frames", f"1..{FRAMES}", "--key", KEY, d / "key.png", "-o", out,
            "--levels", "3", "--iters", "2", "--search", "exact", "--quiet"]


def test_a_worker_killed_mid_chain_changes_no_byte(texsyn, data, cluster, tmp_path):
    make_shot(data, tmp_path)
    run(texsyn, *video_args(tmp_path, tmp_path / "e_%04d.png"))
    cluster.start(3, 1)
    job = subprocess.Popen([str(BUILD / "texsyn"), *map(str, video_args(tmp_path, tmp_path / "c_%04d.png")),
                            "--server", cluster.server.addr], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    # Jobs 1 and 2 are the first frames of the two chains; once job 3 is
    # queued, frames are under way on every worker.
    cluster.server.wait_log(r"job 3 queued")
    assert job.poll() is None, "the sequence ended before the worker was killed"
    cluster.workers[1].proc.kill()
    out, err = job.communicate(timeout=600)
    assert job.returncode == 0, err
    cluster.server.wait_log(r"worker 2 \(\S+\) dropped")
    for f in range(1, FRAMES + 1):
        got, want = tmp_path / f"c_{f:04d}.png", tmp_path / f"e_{f:04d}.png"
        assert got.read_bytes() == want.read_bytes(), f
    assert (tmp_path / "e_0001.png").read_bytes() != (tmp_path / "e_0002.png").read_bytes()
