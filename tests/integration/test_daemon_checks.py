"""The fixtures see the daemons (conftest.check_daemons): a test fails if a
worker it started crashed, or printed an AddressSanitizer, LeakSanitizer or
UBSan report, even when the job it ran came out right. Each case runs
planted_faults.py in a pytest of its own, with faults planted in workers
beside a healthy one."""
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import BUILD, REPO

HERE = Path(__file__).resolve().parent


def run_planted(faults, tmp_path):
    env = dict(os.environ, TEXSYN_PLANTED=",".join(faults), TEXSYN_BUILD=str(BUILD))
    p = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--basetemp",
                        str(tmp_path / "inner"), str(HERE / "planted_faults.py")],
                       capture_output=True, text=True, env=env, cwd=REPO, timeout=300)
    return p.returncode, p.stdout + p.stderr


def reports_of(out, worker):
    """The part of the failure that is about WORKER (workerN)."""
    found = re.findall(rf"^{worker} .*?(?=^worker\d|^=====)|^{worker}'s log .*?(?=^worker\d|^=====)", out,
                       re.M | re.S)
    return "".join(found)


def test_the_planted_test_passes_without_faults(tmp_path):
    """The control: the same test with healthy workers passes, so the
    failures below come from the faults alone."""
    rc, out = run_planted([], tmp_path)
    assert rc == 0 and "1 passed" in out and "error" not in out, out


def test_a_worker_killed_by_a_signal_nobody_sent_fails_the_test(tmp_path):
    rc, out = run_planted(["segv"], tmp_path)
    assert rc == 1 and "1 passed, 1 error" in out, out
    assert "worker1 (pid " in out and "died of SIGSEGV, a signal the test did not send" in out, out


# The planted faults exist only in the sanitizer build (make SAN=1), which
# the sanitized stage of `make test` runs this on. One inner run holds all
# four faults (workers 1-4; worker0 is healthy): each must be named.
@pytest.mark.sanitize
@pytest.mark.asan_only
def test_sanitizer_reports_and_crashes_in_workers_fail_the_test(tmp_path):
    rc, out = run_planted(["overflow", "leak", "undefined", "segv"], tmp_path)
    assert rc == 1 and "1 passed, 1 error" in out, out
    assert "worker0" not in out, out
    want = {"worker1": "ERROR: AddressSanitizer: heap-buffer-overflow",
            "worker2": "ERROR: LeakSanitizer: detected memory leaks",
            "worker3": "runtime error: shift exponent 32",
            "worker4": "AddressSanitizer: SEGV"}  # ASan's handler takes the SIGSEGV
    for worker, report in want.items():
        about = reports_of(out, worker)
        assert f"{worker}'s log" in about and "holds a sanitizer report" in about and report in about, out
    assert "a signal the test did not send" in reports_of(out, "worker4"), out
