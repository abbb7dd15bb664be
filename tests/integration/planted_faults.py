"""A test that passes on its own assertions while some of its workers
misbehave: each fault in TEXSYN_PLANTED (comma-separated) goes into a
worker of its own, beside a healthy one. "segv" kills its worker behind
the fixtures' back; the others are planted in the worker itself
(TEXSYN_PLANT_FAULT, worker/planted.h). Not collected by the suite (the
name does not start with test_): tests/integration/test_daemon_checks.py
runs it in a pytest of its own and expects conftest.check_daemons to fail
it, naming each worker."""
import os
import signal

from conftest import synth

SIZE = (128, 96)
JOB = ("--size", "%dx%d" % SIZE, "--levels", "3")


def test_job_passes_while_workers_misbehave(texsyn, data, cluster, tmp_path):
    ref = data / "textures" / "brick.png"
    want = tmp_path / "embedded.png"
    synth(texsyn, ref, want, SIZE, *JOB[2:])
    faults = [f for f in os.environ["TEXSYN_PLANTED"].split(",") if f]
    healthy = cluster.worker(1)
    workers = {f: cluster.worker(1, prefix=() if f == "segv" else ("env", f"TEXSYN_PLANT_FAULT={f}"))
               for f in faults}
    cluster.start()
    got = tmp_path / "remote.png"
    cluster.texsyn("synth", "--ref", ref, "-o", got, *JOB, "--quiet")
    assert got.read_bytes() == want.read_bytes()
    assert healthy.alive()
    if "segv" in workers:  # a crash the fixtures did not cause
        os.kill(workers["segv"].proc.pid, signal.SIGSEGV)
        workers["segv"].proc.wait()
