"""Shared fixtures: the binaries under test, the shared data, and a runner."""
import json
import os
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
BUILD = Path(os.environ.get("TEXSYN_BUILD", REPO / "build"))
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
SANITIZED = os.environ.get("TEXSYN_SANITIZED") == "1"


def pytest_configure(config):
    config.addinivalue_line("markers", "sanitize: small enough to run under ASan+UBSan too")


@pytest.fixture(scope="session")
def texsyn():
    exe = BUILD / "texsyn"
    assert exe.exists(), f"{exe} is missing: run make first"
    return exe


@pytest.fixture(scope="session")
def data():
    if not (DATA / "textures" / "brick.png").exists():
        pytest.skip(f"shared test data not found at {DATA} (set TEXSYN_DATA)")
    return DATA


def run(exe, *args, env=None, check=True, timeout=600):
    """Runs a texsyn command; returns the CompletedProcess (text mode)."""
    full_env = dict(os.environ)
    full_env.update(env or {})
    p = subprocess.run([str(exe), *map(str, args)], capture_output=True, text=True,
                       env=full_env, timeout=timeout)
    if check and p.returncode != 0:
        raise AssertionError(f"texsyn {' '.join(map(str, args))} failed ({p.returncode}):\n{p.stderr}")
    return p


def synth(exe, ref, out, size, *extra, env=None):
    w, h = size
    report = Path(str(out) + ".json")
    run(exe, "synth", "--ref", ref, "-o", out, "--size", f"{w}x{h}", "--quiet",
        "--report", report, *extra, env=env)
    return json.loads(report.read_text())


def quality(exe, ref, image, samples=1500, wn=7):
    p = run(exe, "quality", "--ref", ref, "--image", image, "--samples", samples, "--wn", wn)
    return json.loads(p.stdout)
