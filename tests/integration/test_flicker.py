"""texsyn flicker on shots cut from aero1.jpg by bench/video_shot.py (a pan
plus a slow zoom): a static sequence scores exactly 0; stylized frames that
are the input frames themselves, which follow the motion by construction,
score near 0 (2.89 when written, 2.49 over the default 48 frames: what bilinear warping and the flow's own
error leave on a textured photograph); independent noise scores high. The
score is the same on a second run. Bad input is refused before any flow is
computed, naming what is wrong. (The flow's bytes are pinned by SHA-256 in
tests/unit/test_flow.c.)"""
import json
import shutil
import subprocess

import pytest

from conftest import BUILD, REPO, run
from pnm import oiiotool

FRAMES = 8


@pytest.fixture(scope="module")
def shot(data, tmp_path_factory):
    d = tmp_path_factory.mktemp("shot")
    subprocess.run(["/usr/bin/python3", REPO / "bench" / "video_shot.py", d / "in_%04d.png", "--frames", str(FRAMES),
                    "--source", data / "aerial" / "aero1.jpg"], check=True, capture_output=True, timeout=120)
    return d


def flicker(texsyn, frames, inp, img, *extra):
    return json.loads(run(texsyn, "flicker", "--frames", frames, "--input", inp, "--image", img, "--json",
                          *extra).stdout)


@pytest.mark.sanitize
def test_a_static_sequence_scores_zero(texsyn, shot, tmp_path):
    for f in range(1, 5):
        shutil.copy(shot / "in_0001.png", tmp_path / f"s{f}.png")
    r = flicker(texsyn, "1..4", tmp_path / "s%d.png", tmp_path / "s%d.png")
    assert r["steps"] == 3 and r["mean"] == 0 and r["worst"] == 0 and r["occluded"] == 0, r
    assert [s["frame"] for s in r["per_step"]] == [2, 3, 4]


def test_the_input_itself_scores_near_zero_and_noise_high(texsyn, shot, tmp_path):
    pattern = shot / "in_%04d.png"
    same = flicker(texsyn, f"1..{FRAMES}", pattern, pattern)
    assert same["steps"] == FRAMES - 1 and 0 < same["mean"] < 4 and same["worst"] < 5, same
    # The zoom in brings nearly every pixel back from the previous frame.
    assert same["occluded"] < 0.05, same
    assert same["flow"].startswith("OpenCV ") and "DIS" in same["flow"]
    for f in range(1, FRAMES + 1):
        oiiotool("--pattern", f"noise:type=uniform:seed={f}", "256x192", "3", "-d", "uint8", "-o",
                 tmp_path / f"n{f}.png")
    noise = flicker(texsyn, f"1..{FRAMES}", pattern, tmp_path / "n%d.png")
    assert noise["mean"] > 25 and noise["mean"] > 10 * same["mean"], (noise, same)
    # The same flows, hence the same score, on a second run.
    assert flicker(texsyn, f"1..{FRAMES}", pattern, pattern) == same


def test_the_text_report_names_the_worst_step(texsyn, shot):
    out = run(texsyn, "flicker", "--frames", "2..5", "--input", shot / "in_%04d.png", "--image",
              shot / "in_%04d.png").stdout.splitlines()
    assert len(out) == 3, out
    assert out[0].startswith("temporal error ") and "over 3 steps (frames 2..5)" in out[0]
    frame = int(out[1].split("frame ")[1].split()[0])
    assert 3 <= frame <= 5 and out[1].endswith(f"against {frame - 1}")
    assert out[2].startswith("occluded ") and "% of the pixels" in out[2]


@pytest.mark.sanitize
def test_bad_input_is_refused_before_any_work(texsyn, shot, tmp_path):
    def refused(*args, code=1, env=None):
        p = run(texsyn, "flicker", *args, check=False, env=env)
        assert p.returncode == code and p.stdout == "", (p.returncode, p.stdout, p.stderr)
        return p.stderr.strip()

    inp = shot / "in_%04d.png"
    assert refused("--frames", "3..3", "--input", inp, "--image", inp, code=2) == \
        "texsyn flicker: --frames 3..3: one frame has no step to score; give at least two"
    assert "need A <= B" in refused("--frames", "3..1", "--input", inp, "--image", inp, code=2)
    assert "--frames, --input and --image are required" in refused("--frames", "1..3", "--input", inp, code=2)
    err = refused("--frames", f"1..{FRAMES + 1}", "--input", inp, "--image", inp)
    assert err == (f"texsyn flicker: --input frame {FRAMES + 1}: cannot read {shot}/in_{FRAMES + 1:04d}.png: "
                   "No such file or directory (nothing was scored)")
    assert "put the frame number in the name" in refused("--frames", "1..2", "--input", shot / "in_0001.png",
                                                         "--image", inp)
    # A stylized frame of another size, and stylized frames of another size than the input.
    for f in (1, 2, 3):
        shutil.copy(shot / f"in_{f:04d}.png", tmp_path / f"o{f}.png")
    oiiotool(shot / "in_0003.png", "--resize", "128x96", "-o", tmp_path / "o3.png")
    err = refused("--frames", "1..3", "--input", inp, "--image", tmp_path / "o%d.png")
    assert f"--image frame 3 ({tmp_path}/o3.png) is 128x96 with 3 channels, frame 1 ({tmp_path}/o1.png) " \
        "256x192 with 3" in err and "must have the first one's size and channels" in err, err
    for f in (1, 2):
        oiiotool(shot / f"in_{f:04d}.png", "--resize", "128x96", "-o", tmp_path / f"h{f}.png")
    assert "--image frames are 128x96, --input frames 256x192: the stylized frames must have their inputs' " \
        "size" in refused("--frames", "1..2", "--input", inp, "--image", tmp_path / "h%d.png")
    for f in (1, 2):
        oiiotool(shot / f"in_{f:04d}.png", "--resize", "24x18", "-o", tmp_path / f"t{f}.png")
    assert "the optical flow needs at least 32x32" in refused("--frames", "1..2", "--input", tmp_path / "t%d.png",
                                                               "--image", tmp_path / "t%d.png")
    # Without its flow library, the command says which path it tried and how to fix it.
    missing = tmp_path / "nope" / "libtexsyn-flow.so"
    err = refused("--frames", "1..2", "--input", inp, "--image", inp, env={"TEXSYN_FLOW_LIB": str(missing)})
    assert str(missing) in err and "TEXSYN_FLOW_LIB" in err and "No such file" in err, err


@pytest.mark.parametrize("program", ["texsyn", "texsyn-server", "texsyn-worker"])
def test_programs_do_not_link_opencv(program):
    """OpenCV and the C++ runtime come with libtexsyn-flow.so, loaded on the first flow only."""
    needed = subprocess.run(["readelf", "-d", BUILD / program], capture_output=True, text=True, check=True).stdout
    assert "libopencv" not in needed and "libstdc++" not in needed, needed
    assert "libopencv_video" in subprocess.run(["readelf", "-d", BUILD / "libtexsyn-flow.so"], capture_output=True,
                                               text=True, check=True).stdout
