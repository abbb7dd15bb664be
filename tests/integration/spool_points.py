"""What test_crashpoints.py and test_disk_faults.py share: a coordinator
under tests/preload/spool_fault.c, which numbers the calls that change its
spool ("points": open for writing, write, fflush, fsync, rename, mkdir,
unlink, rmdir) and kills it at one or fails them, the points it logged,
and a small job lifecycle driven the way a client would.

The lifecycle: job A (64x48, with a report) submitted, watched to its end
and fetched; job B (56x40) submitted and watched; A deleted; B fetched.
One runner (--jobs 1) and checkpoints after whole levels only
(--checkpoint-interval 0), so the points come in the same order on every
run."""
import json
import re
import signal
from pathlib import Path

from conftest import BUILD, DAEMONS, Daemon, jobs_listed, run, synth

SHIM = BUILD / "tests" / "libspool_fault.so"
SERVER_ARGS = ["--jobs", "1", "--checkpoint-interval", "0"]
JOBS = {"A": (64, 48), "B": (56, 40)}


def ref_of(data):
    return data / "textures" / "brick.png"


def job_args(name):
    w, h = JOBS[name]
    return ["--size", f"{w}x{h}", "--levels", "3"]


def expected_outputs(texsyn, data, tmp_path):
    """The embedded run's bytes of each lifecycle job, by name."""
    out = {}
    for name, size in JOBS.items():
        path = tmp_path / f"embedded-{name}.png"
        synth(texsyn, ref_of(data), path, size, "--levels", "3")
        out[name] = path.read_bytes()
    return out


class Point:
    """One line of the shim's log: its number, the call, the path and what
    was done to it ("" when the call was made)."""

    LINE = re.compile(r"(\d+) (\S+) (.*?)(?: !(\S+))?$")

    def __init__(self, line):
        m = self.LINE.match(line)
        assert m, f"not a point: {line!r}"
        self.n, self.call, self.path, self.acted = int(m.group(1)), m.group(2), m.group(3), m.group(4) or ""

    def where(self, spool):
        """The path inside the spool, a temporary's pid as PID."""
        rel = self.path[len(str(spool)):].lstrip("/") or "."
        return re.sub(r"\.tmp-\d+", ".tmp-PID", rel)

    def __repr__(self):
        return f"{self.n} {self.call} {self.path}" + (f" !{self.acted}" if self.acted else "")


def read_points(log):
    """The points of a shim log, in their numbers' order."""
    if not Path(log).exists():
        return []
    return sorted((Point(line) for line in Path(log).read_text().splitlines()), key=lambda p: p.n)


def start_server(tmp, spool, log_name, points_log, fault=None, at=None, while_file=None):
    """A coordinator on spool under the shim, logging its points to
    points_log; with fault, "kill" or an errno name, acted on at point
    `at` or while `while_file` exists. Returns the Daemon, or None if it
    died before it listened (a point of its start-up)."""
    env = [f"LD_PRELOAD={SHIM}", f"TEXSYN_SPOOL_FAULT_DIR={spool}", f"TEXSYN_SPOOL_FAULT_LOG={points_log}"]
    if fault is not None:
        env.append(f"TEXSYN_SPOOL_FAULT={fault}")
    if at is not None:
        env.append(f"TEXSYN_SPOOL_FAULT_AT={at}")
    if while_file is not None:
        env.append(f"TEXSYN_SPOOL_FAULT_WHILE={while_file}")
    assert SHIM.exists(), f"{SHIM} is missing: run make"
    args = ["env", *env, BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", spool, *SERVER_ARGS]
    try:
        return Daemon(args, tmp / log_name)
    except AssertionError:
        d = DAEMONS[-1]
        if fault == "kill":
            d.expect_signal(signal.SIGKILL)
        return None


class Client:
    """The client's side of the lifecycle: what it was told. `ids` maps a
    job's name to the id its submission was acknowledged with; `deleted`
    holds the names whose deletion was acknowledged, `asked_deleted` those
    asked; `served` the names whose fetch succeeded; `errors` the
    failures, (step, stderr)."""

    def __init__(self, server, tmp, data):
        self.addr, self.tmp, self.data = server.addr, tmp, data
        self.ids, self.deleted, self.asked_deleted, self.served, self.errors = {}, set(), set(), set(), []

    def texsyn(self, *args, timeout=120):
        return run(BUILD / "texsyn", *args, "--server", self.addr, check=False, timeout=timeout)

    def step(self, what, name, expected):
        """One step; False once the coordinator has failed it."""
        tmp = self.tmp
        if what == "submit":
            extra = ["--report", tmp / f"unused-{name}.json"] if name == "A" else []
            p = self.texsyn("synth", "--ref", ref_of(self.data), "-o", tmp / f"unused-{name}.png", *job_args(name),
                            *extra, "--detach")
            if p.returncode == 0:
                self.ids[name] = p.stdout.split()[-1]
        elif what == "watch":
            p = self.texsyn("watch", self.ids[name], "--quiet")
        elif what == "fetch":
            out, report = tmp / f"fetched-{name}.png", tmp / f"fetched-{name}.json"
            extra = ["--report", report] if name == "A" else []
            p = self.texsyn("fetch", self.ids[name], "-o", out, *extra)
            if p.returncode == 0:
                # A result the coordinator serves is right, whatever came before.
                assert out.read_bytes() == expected[name], f"job {name} was served other bytes than the embedded run's"
                if name == "A":
                    assert json.loads(report.read_text())["levels"], "job A's report has no levels"
                self.served.add(name)
        else:
            self.asked_deleted.add(name)
            p = self.texsyn("delete", self.ids[name])
            if p.returncode == 0:
                self.deleted.add(name)
        if p.returncode != 0:
            self.errors.append((f"{what} {name}", p.stderr.strip()))
        return p.returncode == 0

    STEPS = [("submit", "A"), ("watch", "A"), ("fetch", "A"), ("submit", "B"), ("watch", "B"), ("delete", "A"),
             ("fetch", "B")]

    def lifecycle(self, expected):
        """The lifecycle's steps until one fails; whether all were made."""
        return all(self.step(what, name, expected) for what, name in self.STEPS)

    def every_step(self, expected):
        """The lifecycle's steps, going on past a failed one: each step of
        a job whose submission was acknowledged."""
        for what, name in self.STEPS:
            if what == "submit" or name in self.ids:
                self.step(what, name, expected)


def listing(server):
    """`texsyn status` of a coordinator: {id: (state, text)}."""
    out = run(BUILD / "texsyn", "status", "--server", server.addr).stdout
    return {r["id"]: (r["state"], r["note"]) for r in jobs_listed(out)}


def job_of(point, spool):
    """The job id a point's path is in (jobs/N/... or jobs/N.deleted), or None."""
    m = re.match(r"jobs/(\d+)(?:\.deleted)?(?:/|$)", point.where(spool))
    return m.group(1) if m else None


def counted_lifecycle(texsyn, data, tmp):
    """The embedded bytes of the lifecycle's jobs, and the spool and the
    points of an undisturbed lifecycle run in tmp (every step
    acknowledged): (expected, spool, points)."""
    expected = expected_outputs(texsyn, data, tmp)
    spool = tmp / "spool"
    server = start_server(tmp, spool, "server.log", tmp / "points.log")
    client = Client(server, tmp, data)
    assert client.lifecycle(expected), client.errors
    # Checked here: a module-scoped fixture runs this, out of the sight of
    # conftest's per-test daemon check.
    assert server.stop() == 0 and server.faults() == [], server.read_log()
    points = read_points(tmp / "points.log")
    assert [p.n for p in points] == list(range(1, len(points) + 1)), "the shim's log has gaps"
    return expected, spool, points


def pick(points, spool, call, where):
    """The first point of call on a path (in the spool) matching where."""
    found = [p.n for p in points if p.call == call and re.fullmatch(where, p.where(spool))]
    assert found, f"no {call} of {where} in the lifecycle:\n" + "\n".join(map(repr, points))
    return found[0]
