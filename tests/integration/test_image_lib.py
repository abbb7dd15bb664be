"""Image I/O is a shared library of its own (libtexsyn-image.so), loaded by
what reads or writes images and by nothing else: the programs do not link
OpenImageIO, the job-plane commands and the worker never load it, and a
library that cannot be found or loaded gives one clear error."""
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from conftest import BUILD, run

LIB = "libtexsyn-image.so"
PROGRAMS = ("texsyn", "texsyn-server", "texsyn-worker")


def traced(cluster, *args):
    """A texsyn command that must succeed, run under the dynamic loader's
    trace of every file it loads (in stderr)."""
    return run(BUILD / "texsyn", *args, "--server", cluster.server.addr, env={"LD_DEBUG": "files"})


def mapped(pid):
    return Path(f"/proc/{pid}/maps").read_text()


@pytest.mark.sanitize
@pytest.mark.parametrize("exe", PROGRAMS)
def test_programs_do_not_link_openimageio(exe):
    out = subprocess.run(["readelf", "-d", str(BUILD / exe)], capture_output=True, text=True,
                         check=True).stdout
    needed = [line.split("[", 1)[1].rstrip("]") for line in out.splitlines() if "(NEEDED)" in line]
    assert needed, out
    assert not [n for n in needed if "OpenImageIO" in n or "stdc++" in n], needed


@pytest.mark.sanitize
def test_job_plane_commands_never_load_the_image_library(data, cluster, tmp_path):
    cluster.start(1, 1)
    ref = data / "textures" / "brick.png"
    # The control: submitting reads the reference here, so it loads both.
    p = traced(cluster, "synth", "--ref", ref, "-o", tmp_path / "x.png", "--size", "64x48", "--levels", "3",
               "--detach")
    assert LIB in p.stderr and "libOpenImageIO" in p.stderr, p.stderr[-2000:]
    job = p.stdout.strip()
    for args in (["watch", job, "--quiet"], ["status"], ["status", job], ["workers"],
                 ["fetch", job, "-o", tmp_path / "f.png"], ["delete", job]):
        trace = traced(cluster, *args).stderr
        assert LIB not in trace and "libOpenImageIO" not in trace, (args, trace[-2000:])
    assert (tmp_path / "f.png").stat().st_size > 0
    # The coordinator loaded it at start; the worker, which never sees an
    # image file, has not loaded it after serving the job.
    assert LIB in mapped(cluster.server.proc.pid)
    worker_maps = mapped(cluster.workers[0].proc.pid)
    assert LIB not in worker_maps and "libOpenImageIO" not in worker_maps


@pytest.mark.sanitize
def test_an_image_library_that_does_not_load_is_named(data, tmp_path):
    ref = data / "textures" / "brick.png"
    bad = tmp_path / "nope" / LIB
    p = run(BUILD / "texsyn", "synth", "--ref", ref, "-o", tmp_path / "o.png", "--size", "64x48",
            env={"TEXSYN_IMAGE_LIB": bad}, check=False)
    assert p.returncode == 1
    assert str(bad) in p.stderr and "TEXSYN_IMAGE_LIB" in p.stderr and "No such file" in p.stderr
    assert not (tmp_path / "o.png").exists()
    # A coordinator without image I/O refuses to start, saying why.
    s = subprocess.run([str(BUILD / "texsyn-server"), "--listen", "127.0.0.1:0", "--spool",
                        str(tmp_path / "spool")], capture_output=True, text=True, timeout=60,
                       env={**os.environ, "TEXSYN_IMAGE_LIB": str(bad)})
    assert s.returncode == 1 and str(bad) in s.stderr, s.stderr


@pytest.mark.sanitize
def test_the_library_is_found_next_to_the_program_or_in_the_install_directory(data, tmp_path):
    ref = data / "textures" / "brick.png"
    env = {k: v for k, v in os.environ.items() if k != "TEXSYN_IMAGE_LIB"}
    alone = tmp_path / "alone"
    alone.mkdir()
    shutil.copy(BUILD / "texsyn", alone)
    p = subprocess.run([str(alone / "texsyn"), "quality", "--ref", ref, "--image", ref], capture_output=True,
                       text=True, env=env, timeout=120)
    assert p.returncode == 1
    assert str(alone / LIB) in p.stderr and "make install" in p.stderr, p.stderr
    # The layout of `make install`: PREFIX/bin and PREFIX/lib/texsyn.
    (tmp_path / "prefix" / "bin").mkdir(parents=True)
    (tmp_path / "prefix" / "lib" / "texsyn").mkdir(parents=True)
    shutil.copy(BUILD / "texsyn", tmp_path / "prefix" / "bin")
    shutil.copy(BUILD / LIB, tmp_path / "prefix" / "lib" / "texsyn")
    p = subprocess.run([str(tmp_path / "prefix" / "bin" / "texsyn"), "quality", "--ref", ref, "--image", ref,
                        "--samples", "50"], capture_output=True, text=True, env=env, timeout=120)
    assert p.returncode == 0, p.stderr
