"""texsyn video on a pool of 3 workers, one of them killed while a chain's
frame is being stylized: the surviving workers take its slices and every
frame is the embedded run's bytes (issue 27, point 3); and the operations
page (--http) showing the sequence's frames as they finish. The shot is cut
from aero1.jpg by bench/video_shot.py; the key is its middle frame plus
blurred noise, so two chains (backward and forward) run side by side."""
import json
import re
import signal
import subprocess

import pytest

from conftest import BUILD, REPO, run
from pnm import oiiotool, pixels_of
from test_http import chromium_dom, get, http_addr, wait_until

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


def sequences(base):
    code, _, body = get(base + "/status.json")
    assert code == 200, body
    return json.loads(body)["sequences"]


def settled(base):
    """The page's one sequence once none of its frames is queued or running."""
    seqs = sequences(base)
    if len(seqs) != 1:
        return None
    states = [f["state"] for c in seqs[0]["chains"] for f in c["frames"]]
    return seqs[0] if states and all(s == "done" for s in states) else None


def strip_of(dom, key, end):
    """The frames a chain's row of the page shows: (frame, job) of each
    thumbnail, in the order shown."""
    row = re.search(rf'<tr class="chain" data-key="{key}" data-end="{end}">(.*?)</tr>', dom, re.S)
    assert row, dom
    return [(int(f), int(j)) for f, j in re.findall(r'<a href="/jobs/(?:\d+)/thumb.png"><img class="frame" '
                                                   r'data-frame="(\d+)" data-job="(\d+)" src="/jobs/\2/small.png"',
                                                   row.group(1))]


def box_average(image, w, h):
    """image's (W, H, C, pixels) at w x h, each pixel the mean of the
    source pixels whose box it is (server/http/thumb.c)."""
    sw, sh, c, px = image
    out = bytearray()
    for y in range(h):
        y0, y1 = y * sh // h, max((y + 1) * sh // h, y * sh // h + 1)
        for x in range(w):
            x0, x1 = x * sw // w, max((x + 1) * sw // w, x * sw // w + 1)
            for k in range(c):
                box = [px[(sy * sw + sx) * c + k] for sy in range(y0, y1) for sx in range(x0, x1)]
                out.append((2 * sum(box) + len(box)) // (2 * len(box)))
    return bytes(out)


@pytest.mark.sanitize
def test_the_operations_page_shows_the_sequence_as_its_frames_finish(texsyn, data, cluster, tmp_path):
    """The client stopped after the chains' first frames: the page (in
    chromium) shows the one sequence with only its finished frames; once
    the client goes on, all 7 frames (3 backward from key 4, 4 forward) in
    frame order, each a small thumbnail (64x48) linked to the larger one,
    which decodes to the frame itself (96x72 is under its 160 px)."""
    make_shot(data, tmp_path)
    cluster.start(1, 1, "--http", "127.0.0.1:0")
    base = "http://" + http_addr(cluster.server)
    args = [str(a) for a in video_args(tmp_path, tmp_path / "c_%04d.png") if a != "--quiet"]
    p = subprocess.Popen([str(BUILD / "texsyn"), *args, "--server", cluster.server.addr], stderr=subprocess.PIPE,
                         text=True)
    try:
        check_the_page(p, base, tmp_path)
    finally:
        if p.poll() is None:  # a failed check leaves no client behind
            p.kill()
            p.wait()


def check_the_page(p, base, tmp_path):
    """The checks of the test above, on its running client p."""
    log = []
    for line in p.stderr:  # the second round starts: frames 3 and 5 are finished
        log.append(line)
        if f"key {KEY} backward, frame 2 " in line:
            p.send_signal(signal.SIGSTOP)
            break
    try:
        seq = wait_until("the submitted frames to finish", lambda: settled(base))
        dom = chromium_dom(base + "/")
    finally:
        p.send_signal(signal.SIGCONT)
    assert seq["name"] == "c_%04d.png" and seq["frames"] == [1, FRAMES] and seq["jobs"] == FRAMES - 1, seq
    partial = {(c["key"], c["end"]): [f["frame"] for f in c["frames"]] for c in seq["chains"]}
    assert partial[(KEY, 1)][-1:] == [3] and partial[(KEY, FRAMES)][:1] == [5], partial
    assert 2 <= seq["done"] < FRAMES - 1 and seq["done"] == sum(len(f) for f in partial.values()), seq
    assert re.search(r'<section class="sequence" data-id="[0-9a-f]{16}"><h3>c_%04d.png</h3>', dom), dom
    assert f'<span class="done">{seq["done"]}</span> of <span class="jobs">{FRAMES - 1}</span>' in dom, dom
    assert [f for f, _ in strip_of(dom, KEY, 1)] == partial[(KEY, 1)]
    assert [f for f, _ in strip_of(dom, KEY, FRAMES)] == partial[(KEY, FRAMES)]

    log += p.stderr.readlines()
    assert p.wait(timeout=600) == 0, "".join(log)
    seq = settled(base)
    assert seq is not None and seq["done"] == FRAMES - 1, seq
    dom = get(base + "/")[2].decode()
    shown = strip_of(dom, KEY, 1) + strip_of(dom, KEY, FRAMES)
    assert [f for f, _ in shown] == [1, 2, 3, 5, 6, 7, 8], shown
    for f, job in shown:
        for name in ("thumb", "small"):
            code, headers, body = get(f"{base}/jobs/{job}/{name}.png")
            assert code == 200 and headers["Content-Type"] == "image/png", (f, name, code, body[:200])
            assert headers["Cache-Control"] == "private, max-age=3600"  # a finished result never changes
            (tmp_path / f"{name}.png").write_bytes(body)
            assert (tmp_path / "spool" / "jobs" / str(job) / f"{name}.png").read_bytes() == body  # kept, made once
        # 96x72: the thumbnail is the frame itself (under 160 px, never
        # scaled); the strip's is 64x48, each pixel its box of the frame
        # averaged (within 1 for the rounding of a tie).
        frame = pixels_of(tmp_path / f"c_{f:04d}.png", tmp_path)
        assert pixels_of(tmp_path / "thumb.png", tmp_path) == frame, f
        w, h, c, small = pixels_of(tmp_path / "small.png", tmp_path)
        assert (w, h, c) == (64, 48, 3), (f, w, h, c)
        assert max(abs(a - b) for a, b in zip(small, box_average(frame, 64, 48))) <= 1, f
