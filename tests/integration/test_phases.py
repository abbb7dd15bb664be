"""Kills at every phase of a job, each triggered by a frame the hostile
proxy (hostile.py) sees, never by a time: a worker SIGKILLed when the
coordinator sends it 'C' (calibrating a worker that joins mid-job), 'N' (a
slice load), the 'R' that moves its replica to the next level (between two
levels), half-way through forwarding one of its 'V' answers, and right
after the job's cancel while one of its answers is held; and the
coordinator itself SIGSTOPped for 3 s mid-job, then continued.

Each job ends with the embedded run's bytes (or canceled, where that is the
point), and the coordinator's log names the victim as dropped (or refused,
for a worker that had not joined the pool yet) while the job ran - after
a cancel, whenever the coordinator next looks at it.

The job: texsyn synth of brick.png at 192x144, 3 levels (test_hostile.py's),
on an honest worker and a hostile one behind the proxy.
"""
import re
import signal
import struct
import threading
import time
from pathlib import Path

import pytest

from conftest import BUILD, Daemon, run
from hostile import HostileProxy, Rule, dropped_lines

pytestmark = pytest.mark.long


def job(data, out):
    return ["synth", "--ref", data / "textures" / "brick.png", "-o", out, "--size", "192x144", "--levels", "3",
            "--quiet", "--copy-map-raw", str(out) + ".raw"]


def outputs(out):
    return Path(out).read_bytes(), Path(str(out) + ".raw").read_bytes()


@pytest.fixture(scope="module")
def want(texsyn, data, tmp_path_factory):
    out = tmp_path_factory.mktemp("embedded") / "embedded.png"
    run(texsyn, *job(data, out), "--embedded")
    return outputs(out)


def start(cluster, tmp_path, rules, *server_args):
    """An honest worker, a hostile one behind a proxy armed with rules, and
    the coordinator; returns the honest worker, the hostile one, the proxy."""
    honest, hostile = cluster.worker(1), cluster.worker(1)
    proxy = HostileProxy(hostile.addr, hostile)
    proxy.arm(rules)
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                             "--workers", f"{honest.addr},{proxy.addr}", *server_args], tmp_path / "server.log")
    cluster.wait_ready(2)
    return honest, hostile, proxy


def job_span(log, jid=1):
    """The log between job jid's queueing and its end."""
    m = re.search(rf"job {jid} queued from .*?job {jid} (done in|failed:|canceled:)[^\n]*", log, re.S)
    assert m, f"job {jid} never ended in the log:\n{log}"
    return m.group(0)


def assert_dropped_during_job(log, addr, what):
    span = job_span(log)
    assert dropped_lines(span, addr), f"{what}: the victim ({addr}) was not dropped while the job ran:\n{log}"


def kill_on(side, on, nth=1, where=None):
    return Rule(on, side=side, nth=nth, where=where, action="kill")


@pytest.mark.parametrize("phase", ["N", "V-half", "R-next"])
def test_a_worker_killed_at_a_phase_changes_nothing(data, cluster, tmp_path, want, phase):
    """'N': the 3rd slice load sent to the victim (a set of level 1);
    'V-half': its 20th answer of 32 results or more cut half-way, the
    worker killed before the rest; 'R-next': the first next-level message
    ('R', op 2) sent to it."""
    wide = lambda f: struct.unpack_from("<I", f.payload, 8)[0] >= 32
    rule = {"N": kill_on("request", "N", nth=3),
            "V-half": Rule("V", nth=20, where=wide, action="truncate", how="half", then="kill"),
            "R-next": kill_on("request", "R", where=lambda f: f.info.get("op") == 2)}[phase]
    honest, hostile, proxy = start(cluster, tmp_path, [rule])
    try:
        out = tmp_path / "cluster.png"
        cluster.texsyn(*job(data, out))
    finally:
        proxy.close()
    log = cluster.server.read_log()
    assert rule.fired.is_set(), f"the job ended before the trigger: {proxy.events}"
    assert outputs(out) == want, f"a kill at {phase} changed the result\n{log}"
    assert not hostile.alive(), "the victim survived its kill"
    assert_dropped_during_job(log, proxy.addr, phase)
    assert not dropped_lines(log, honest.addr), f"the honest worker was dropped\n{log}"


def test_a_worker_killed_while_calibrated_mid_job_changes_nothing(data, cluster, tmp_path, want):
    """The honest worker sits behind a passive proxy whose 100th query
    batch starts a second worker, joining (--join) through a hostile proxy
    that kills it when the coordinator sends it 'C'."""
    honest = cluster.worker(1)
    passive = HostileProxy(honest.addr, honest)
    joiners = []
    joined = threading.Event()

    def join(link, f):
        joiners.append(cluster.worker(1, "--join", hostile.addr))
        joined.set()

    def kill(link, f):
        assert joined.wait(10)
        joiners[0].proc.send_signal(signal.SIGKILL)

    start_join = Rule("V", side="request", nth=100, action="call", fn=lambda link, f: threading.Thread(
        target=join, args=(link, f), daemon=True).start())
    passive.arm([start_join])
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                             "--workers", passive.addr, "--calibrate-ms", "200"], tmp_path / "server.log")
    cluster.wait_ready(1)
    hostile = HostileProxy(cluster.server.addr, joining=True)
    killed = Rule("C", side="request", action="call", fn=kill)
    hostile.arm([killed])
    try:
        out = tmp_path / "cluster.png"
        cluster.texsyn(*job(data, out))
    finally:
        passive.close()
        hostile.close()
    log = cluster.server.read_log()
    assert killed.fired.is_set(), f"no worker joined during the job: {hostile.events}"
    assert outputs(out) == want, f"a worker killed while calibrated changed the result\n{log}"
    peer = hostile.links[0].peer
    span = job_span(log)
    assert f"worker joining from {peer}" in span and re.search(rf"worker {re.escape(peer)} refused: ", span), \
        f"the joining victim ({peer}) is not named as refused while the job ran:\n{log}"
    assert not dropped_lines(log), f"a worker of the pool was dropped\n{log}"


def test_a_worker_killed_during_a_cancel(data, cluster, tmp_path, want):
    """The victim's 60th answer is held 3 s; meanwhile the job is cancelled
    and the victim killed (its connection closes, as a dead process's
    does). The job ends canceled; the victim is dropped (by the cancelled
    job's exchange, a heartbeat or the next job: whichever sees it first);
    the honest worker stays in the pool (same id, never dropped) and the
    next job gives the embedded bytes."""
    held = Rule("V", nth=60, action="delay", ms=3000)
    honest, hostile, proxy = start(cluster, tmp_path, [held])
    try:
        jid = cluster.submit(data / "textures" / "brick.png", "--size", "192x144", "--levels", "3")
        assert held.fired.wait(60), f"the job never sent a 60th batch to the victim: {proxy.events}"
        cluster.texsyn("cancel", jid)
        hostile.proc.send_signal(signal.SIGKILL)
        proxy.cut_all()
        cluster.texsyn("watch", jid, check=False)
        state = cluster.texsyn("status", jid).stdout.split()[1]
        assert state == "canceled", cluster.server.read_log()
        out = tmp_path / "next.png"
        cluster.texsyn(*job(data, out))
        log = cluster.server.read_log()
        assert outputs(out) == want, f"the job after the cancel differs from the embedded run\n{log}"
        assert dropped_lines(log, proxy.addr), f"the killed worker ({proxy.addr}) was never dropped\n{log}"
        honest_ids = {wid for wid, peer in re.findall(r"worker (\d+) \(([^,\s)]+), ", log) if peer == honest.addr}
        assert len(honest_ids) == 1 and not dropped_lines(log, honest.addr), f"the honest worker left the pool\n{log}"
    finally:
        proxy.close()


def test_the_coordinator_stopped_mid_job_changes_nothing(data, cluster, tmp_path, want):
    """SIGSTOP of the coordinator when it sends the victim its 100th query
    batch, SIGCONT 3 s later (past every deadline): the job's bytes are the
    embedded run's, and the pool has both workers ready afterwards."""
    stop = Rule("V", side="request", nth=100, action="signal", sig=signal.SIGSTOP, resume_after=3.0)
    honest, hostile, proxy = start(cluster, tmp_path, [stop])
    stop.params["target"] = cluster.server
    try:
        out = tmp_path / "cluster.png"
        t0 = time.time()
        cluster.texsyn(*job(data, out))
        took = time.time() - t0
    finally:
        proxy.close()
    log = cluster.server.read_log()
    assert stop.fired.is_set(), f"the job ended before the coordinator was stopped: {proxy.events}"
    assert took >= 3.0, f"the job took {took:.1f} s: it was not stopped while it ran"
    assert outputs(out) == want, f"a stopped coordinator changed the result\n{log}"
    cluster.wait_ready(2)
