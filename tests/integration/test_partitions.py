"""Network partitions and half-open TCP between the coordinator and its
workers, each worker in a network namespace of its own (netns.py), while a
real job runs through the fault:

  * a partition shorter than every deadline: ridden out, nobody dropped;
  * a symmetric partition of one worker mid-job that heals after 6 s;
  * asymmetric ones: coordinator -> worker dropped while worker ->
    coordinator flows, and the reverse;
  * half-open TCP: the victim's link cut both ways, the victim killed (its
    FIN and RST are lost) and its namespace deleted, so the coordinator
    hears nothing and must notice by its own deadlines; the host then
    comes back with a fresh worker on the same address.

After a partition heals the coordinator dials the victim's --workers
address again and the victim must get work again in the same job. Every
case: the output bytes equal the embedded run's, the coordinator's log
names the victim as dropped while the job ran (or, for the short one, not
at all), and the pool ends with the workers expected.

The faults are timed by the job's own progress (its checkpoint after
level 2, and the victim holding a slice), never by a guess of how long the
job takes. Needs root and nft (deploy/install-deps.sh); the long cases run
in `make test-faults`."""
import os
import re
import signal
import subprocess
import time

import pytest

import netns
from conftest import BUILD, Daemon, synth, workers_listed

BRICK = "textures/brick.png"
# The long cases' job: long enough (about 20 s on 3 workers here, quiet)
# that a 6 s partition, the drop, the heal, the redial and the victim's new
# slice all fall inside it, the fault coming at the start of level 1
# (a quarter of the job's time, level 0 the rest).
LONG_JOB = ("--size", "2048x1024")
# The short case's job: about 2 s on 3 workers. It cannot end during the
# cut: the victim holds a slice every batch needs (the test's 7 s in all).
SHORT_JOB = ("--size", "512x384")
COMMON = ("--usage-weight", "1")
PARTITION_S = 6.0       # past the 2 s batch deadline and the 2S+1 = 5 s heartbeat
SHORT_PARTITION_S = 1.0
VICTIM = 1              # the slot cut; slots 0 and 2 keep working
WORKERS = 3
# What the coordinator says when its own clock, not the peer, ended a
# worker: a batch or heartbeat deadline, or both planes silent (Modbus).
# A partition sends nothing, so nothing else may be the reason.
DEADLINE_REASON = re.compile(r"no answer|silent")


class Expected:
    """The embedded runs' bytes of each job, made when first asked for (the
    default suite needs only the short one)."""

    def __init__(self, texsyn, data, tmp):
        self.texsyn, self.data, self.tmp, self.got = texsyn, data, tmp, {}

    def __getitem__(self, name):
        if name not in self.got:
            job = {"long": LONG_JOB, "short": SHORT_JOB}[name]
            w, h = map(int, job[1].split("x"))
            synth(self.texsyn, self.data / BRICK, self.tmp / f"{name}.png", (w, h), *COMMON)
            self.got[name] = (self.tmp / f"{name}.png").read_bytes()
        return self.got[name]


@pytest.fixture(scope="module")
def expected(texsyn, data, tmp_path_factory):
    return Expected(texsyn, data, tmp_path_factory.mktemp("expected"))


@pytest.fixture
def net():
    why = netns.missing()
    if why:
        pytest.fail(f"network partitions: {why}", pytrace=False)
    n = netns.Net(WORKERS).create()
    yield n
    n.close()


@pytest.fixture
def cluster_in(net, tmp_path):
    """An NsCluster, its daemons stopped before the namespaces go."""
    cl = NsCluster(net, tmp_path)
    yield cl
    cl.stop()


class NsCluster:
    """A coordinator in the coordinator's namespace (listening on all its
    addresses: clients reach it on its loopback, workers on their slot's
    veth) and a --listen worker in each slot, with a shared secret (the
    peers are not on loopback)."""

    def __init__(self, net, tmp):
        self.net, self.tmp = net, tmp
        self.secret = tmp / "secret"
        self.secret.write_text(os.urandom(16).hex())
        self.secret.chmod(0o600)
        self.env = dict(os.environ, TEXSYN_SECRET_FILE=str(self.secret))
        self.workers = {}   # slot -> Daemon
        self.server = None

    def stop(self):
        if self.server:
            self.server.stop()
        for w in self.workers.values():
            w.stop()

    def worker(self, slot, addr=None, name=None):
        addr = addr or f"{self.net.worker_ip(slot)}:0"
        name = name or f"w{slot}"
        w = Daemon(self.net.in_worker(slot, BUILD / "texsyn-worker", "--listen", addr, "--threads", 1,
                                      "--name", name, "--secret-file", self.secret,
                                      "--modbus", f"{self.net.worker_ip(slot)}:0",
                                      "--modbus-allow", self.net.coord_ip(slot)),
                   self.tmp / f"{name}.log")
        self.workers[slot] = w
        return w

    def start(self, *server_args):
        for slot in range(WORKERS):
            self.worker(slot)
        self.server = Daemon(self.net.in_coord(
            BUILD / "texsyn-server", "--listen", "0.0.0.0:0", "--spool", self.tmp / "spool", "--secret-file",
            self.secret, "--workers", ",".join(self.workers[s].addr for s in range(WORKERS)), *server_args),
            self.tmp / "server.log")
        self.addr = f"127.0.0.1:{self.server.port}"
        self.wait_pool(WORKERS)
        return self

    def texsyn(self, *args, timeout=60):
        p = subprocess.run(self.net.in_coord(BUILD / "texsyn", *args, "--server", self.addr), capture_output=True,
                           text=True, env=self.env, timeout=timeout)
        assert p.returncode == 0, f"texsyn {' '.join(map(str, args))}: {p.stderr}"
        return p.stdout

    def pool(self):
        """{address: state} from `texsyn workers`."""
        rows = {}
        for w in workers_listed(self.texsyn("workers")):
            if w["state"] != "dead":
                rows[w["addr"]] = w["state"]
        return rows

    def wait_pool(self, n, timeout=60):
        deadline = time.time() + timeout
        while time.time() < deadline:
            ready = sorted(a for a, s in self.pool().items() if s == "active")
            if len(ready) >= n:
                return ready
            time.sleep(0.1)
        raise AssertionError(f"{n} workers not ready within {timeout} s: {self.pool()}\n{self.server.read_log()}")

    def registers(self, slot):
        """The slot's worker's Modbus registers, read from the coordinator's
        namespace (across its veth)."""
        p = subprocess.run(self.net.in_coord(BUILD / "texsyn", "modbus", self.workers[slot].modbus),
                           capture_output=True, text=True, timeout=30)
        assert p.returncode == 0, f"texsyn modbus {self.workers[slot].modbus}: {p.stderr}"
        return dict(line.split(" ", 1) for line in p.stdout.splitlines())

    def submit(self, data, out, job):
        """`texsyn synth --server` in the background (the coordinator's
        namespace); returns the Popen and the job's id."""
        before = len(re.findall(r"job \d+ queued from", self.server.read_log()))
        args = self.net.in_coord(BUILD / "texsyn", "synth", "--server", self.addr, "--ref", data / BRICK, "-o", out,
                                 *job, *COMMON, "--quiet")
        proc = subprocess.Popen(args, stderr=subprocess.PIPE, text=True, env=self.env)
        deadline = time.time() + 60
        while time.time() < deadline:
            ids = re.findall(r"job (\d+) queued from", self.server.read_log())
            if len(ids) > before:
                return proc, ids[-1]
            assert proc.poll() is None, f"the job ended before it was queued: {proc.communicate()[1]}"
            time.sleep(0.02)
        raise AssertionError(f"no job queued:\n{self.server.read_log()}")


def finish(proc, timeout=600):
    _, err = proc.communicate(timeout=timeout)
    return proc.returncode, err


def victim_addr(cl):
    return cl.workers[VICTIM].addr


def wait_victim_loaded(cl, jid):
    """The fault's moment: the job has finished level 2 and the victim
    holds a slice of it (its own register)."""
    cl.server.wait_log(rf"job {jid}: checkpoint after level 2")
    deadline = time.time() + 60
    while time.time() < deadline:
        if int(cl.registers(VICTIM)["vectors"]) > 0:
            return
        time.sleep(0.02)
    raise AssertionError("the victim never held a slice of the job")


def drop_lines(log, addr):
    """The coordinator's 'worker N (ADDR) dropped: WHY' lines for addr, as
    (position in the log, worker id, why)."""
    return [(m.start(), m.group(1), m.group(2))
            for m in re.finditer(rf"worker (\d+) \({re.escape(addr)}\) dropped: (.*)", log)]


def ready_lines(log, addr):
    return [(m.start(), m.group(1)) for m in re.finditer(rf"worker (\d+) \({re.escape(addr)}, [^)]*\) ready", log)]


def done_at(log, jid):
    m = re.search(rf"job {jid} done in", log)
    assert m, f"job {jid} never logged done:\n{log[-3000:]}"
    return m.start()


def check_output(out, want, code, err, log, what):
    assert code == 0, f"{what}: the job failed: {err}\n{log[-3000:]}"
    assert out.read_bytes() == want, f"{what}: the output differs from the embedded run"


def partitioned_job(cl, data, tmp_path, expected, direction):
    """Runs the long job, cuts the victim in `direction` for PARTITION_S at
    the start of level 1, heals; checks the victim was dropped while the
    job ran, was dialled again and got work again in the same job."""
    what = f"partition {direction} of {victim_addr(cl)} for {PARTITION_S} s"
    out = tmp_path / "out.png"
    job, jid = cl.submit(data, out, LONG_JOB)
    wait_victim_loaded(cl, jid)
    cl.net.partition(VICTIM, direction)
    cut_at = time.time()
    # The drop must come while the job runs: wait for it with the job alive.
    m = cl.server.wait_log(rf"worker (\d+) \({re.escape(victim_addr(cl))}\) dropped: (.*)", timeout=60)
    assert job.poll() is None, f"{what}: the job ended before the victim was dropped"
    detected = time.time() - cut_at
    time.sleep(max(0.0, PARTITION_S - detected))
    dropped = cl.net.dropped(VICTIM)
    cl.net.heal(VICTIM)
    # Dialled again and admitted: then the victim's batch count must grow.
    deadline = time.time() + 60
    while time.time() < deadline and len(ready_lines(cl.server.read_log(), victim_addr(cl))) < 2:
        assert job.poll() is None, f"{what}: the job ended before the victim was dialled again"
        time.sleep(0.05)
    assert len(ready_lines(cl.server.read_log(), victim_addr(cl))) >= 2, f"{what}: the victim was not dialled again"
    assert job.poll() is None, f"{what}: the job ended as the victim came back: make LONG_JOB longer"
    back = time.time() - cut_at
    batches_back = int(cl.registers(VICTIM)["batches"])
    code, err = finish(job)
    left = time.time() - cut_at - back
    log = cl.server.read_log()
    check_output(out, expected["long"], code, err, log, what)
    end = done_at(log, jid)
    drops = drop_lines(log, victim_addr(cl))
    readies = ready_lines(log, victim_addr(cl))
    assert drops and drops[0][0] < end, f"{what}: the victim was not dropped during the job:\n{log[-3000:]}"
    assert readies[1][0] > drops[0][0], f"{what}: no re-admission after the drop"
    resliced = [r.start() for r in re.finditer(r"set \d+ generation \d+ over 3 workers", log)]
    assert any(readies[1][0] < p < end for p in resliced), \
        f"{what}: the job was not sliced again over 3 workers after the victim came back:\n{log[-3000:]}"
    assert int(cl.registers(VICTIM)["batches"]) > batches_back, \
        f"{what}: the victim answered no batch after it came back"
    assert sum(dropped.values()) > 0, f"{what}: the rules dropped nothing: {dropped}"
    assert DEADLINE_REASON.search(drops[0][2]), f"{what}: dropped for a reason a partition cannot give: {drops[0][2]}"
    assert sorted(cl.wait_pool(WORKERS)) == sorted(w.addr for w in cl.workers.values())
    return {"why": m.group(2), "detected_s": round(detected, 2), "back_s": round(back, 2), "job_left_s": round(left, 1),
            "dropped_packets": dropped}


def test_partition_shorter_than_the_deadlines_is_ridden_out(data, net, cluster_in, tmp_path, expected):
    """1 s both ways, against a 5 s batch deadline and heartbeat: TCP
    retransmits what was lost once the link heals (at most 1.4 s after it
    was sent: 0.2 + 0.4 + 0.8 s of backoff), the batch completes in time and
    nobody is dropped. The rules' counters prove traffic was cut mid-job."""
    cl = cluster_in.start("--batch-timeout", "5", "--heartbeat", "5")
    out = tmp_path / "out.png"
    job, jid = cl.submit(data, out, SHORT_JOB)
    wait_victim_loaded(cl, jid)
    net.partition(VICTIM, "both")
    time.sleep(SHORT_PARTITION_S)
    dropped = net.dropped(VICTIM)
    net.heal(VICTIM)
    running = job.poll() is None
    code, err = finish(job)
    log = cl.server.read_log()
    check_output(out, expected["short"], code, err, log, "short partition")
    assert running, "the job ended during the partition: it did not run through it"
    assert sum(dropped.values()) > 0, f"the partition cut no traffic: {dropped}"
    assert not drop_lines(log, victim_addr(cl)), f"a 1 s partition dropped the victim:\n{log}"
    assert "dropped:" not in log, f"a worker was dropped:\n{log}"
    assert len(ready_lines(log, victim_addr(cl))) == 1, "the victim was admitted twice"
    assert sorted(cl.wait_pool(WORKERS)) == sorted(w.addr for w in cl.workers.values())


@pytest.mark.long
@pytest.mark.parametrize("direction", ["both", "to_worker", "to_coordinator"])
def test_partition_drops_the_victim_which_rejoins_and_works_again(data, cluster_in, tmp_path, expected, direction):
    """Default deadlines (batch 2 s, heartbeat 2 s). both: nothing crosses;
    to_worker: the coordinator's frames are lost, the worker's flow (its
    ACKs and anything it had to say); to_coordinator: the victim gets its
    queries and answers them into the void."""
    cl = cluster_in.start()
    seen = partitioned_job(cl, data, tmp_path, expected, direction)
    print(f"partition {direction}: victim dropped {seen['detected_s']} s after the cut ({seen['why']}), ready "
          f"again {seen['back_s']} s after it, the job ran {seen['job_left_s']} s more; packets dropped "
          f"{seen['dropped_packets']}")


@pytest.mark.long
def test_half_open_worker_that_vanishes_is_noticed_by_the_deadlines(data, net, cluster_in, tmp_path, expected):
    """The victim's link is cut both ways, then it is SIGKILLed (the FIN or
    RST its kernel sends is lost) and its namespace deleted: a host that lost
    power. The coordinator's socket stays established with nobody behind
    it; only its deadlines can tell. The job finishes on the other two; the
    pool holds two ready workers while the address stays dead; a fresh
    worker on the same address (the host back) is dialled again."""
    cl = cluster_in.start()
    addr = victim_addr(cl)
    what = f"half-open {addr}"
    out = tmp_path / "out.png"
    job, jid = cl.submit(data, out, LONG_JOB)
    wait_victim_loaded(cl, jid)
    net.partition(VICTIM, "both")
    victim = cl.workers[VICTIM]
    victim.proc.send_signal(signal.SIGKILL)
    victim.proc.wait()
    dropped = net.dropped(VICTIM)
    net.vanish(VICTIM)
    cut_at = time.time()
    m = cl.server.wait_log(rf"worker (\d+) \({re.escape(addr)}\) dropped: (.*)", timeout=60)
    assert job.poll() is None, f"{what}: the job ended before the victim was dropped"
    detected = time.time() - cut_at
    code, err = finish(job)
    log = cl.server.read_log()
    check_output(out, expected["long"], code, err, log, what)
    drops = drop_lines(log, addr)
    assert drops[0][0] < done_at(log, jid), f"{what}: not dropped during the job"
    assert DEADLINE_REASON.search(drops[0][2]), f"{what}: the coordinator heard of the death ({drops[0][2]}): " \
        "the half-open connection leaked a FIN or RST"
    assert sum(dropped.values()) > 0, f"{what}: the rules dropped nothing before the kill: {dropped}"
    ready = cl.wait_pool(WORKERS - 1)
    assert addr not in ready and len(ready) == WORKERS - 1, f"{what}: pool {cl.pool()}"
    assert re.search(rf"worker {re.escape(addr)}: .*dialling it again", log), \
        f"{what}: the coordinator does not say it dials the dead address again:\n{log[-2000:]}"
    # The host comes back: its namespace, a fresh worker on the old address.
    net.add_slot(VICTIM)
    cl.worker(VICTIM, addr=addr, name="w1-back")
    assert sorted(cl.wait_pool(WORKERS)) == sorted(w.addr for w in cl.workers.values())
    print(f"half-open: victim dropped {detected:.2f} s after its namespace went ({m.group(2)}); packets dropped "
          f"before the kill {dropped}")
