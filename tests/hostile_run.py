#!/usr/bin/python3
"""Seeded random schedules of a hostile worker (issue 25): `make test-hostile
SCHEDULES=2000` runs this; tests/integration/test_hostile.py runs a few.

For every engine - MRF synthesis, hole filling, aerial, stylize (exact and
PatchMatch), segment - on inputs small enough that a job takes well under
a second, one long-lived coordinator (a batch) serves two workers: one
honest, dialled directly, and one behind a HostileProxy
(tests/integration/hostile.py). Each schedule arms the proxy with one or
two random rules - a frame type the coordinator receives (I, C, N, R, V, G,
T, Q, H; E and the others forged), the nth such frame of this engine's job,
and an action: dup, reorder, delay, drop, truncate, cut half-way, forge
(type, id, body drawn at random), cut, kill or SIGSTOP the worker, or kill /
stop / cut when the coordinator sends a frame type - then runs the engine's
job through the CLI and checks the job history:

  identical  the job is done, its outputs are the embedded run's bytes
  failed     the job failed, with a reason (the CLI's and the spool's)
  different  the job is done with other bytes: a silently wrong result
  lost       anything else: a job not in the history, not ended, ended
             twice, a client that hung, a coordinator that died

`different` and `lost` must never happen. Forged answers that are
indistinguishable from a worker's true answer (a well-formed 'V' or 'T'
with the right id, set and generation, and results inside its slice) are
lies no protocol check can catch, and are not drawn: every forgery carries
something a coordinator can check.

The seed is printed and changes per run; --seed S replays a run, --only K
one schedule of it (its rules are in the JSON with the seed). Writes
OUT/hostile.json and OUT/hostile.md: the outcomes per engine and action,
the CPU, the seed and the time per schedule.

Two engines run at once (--parallel), each with its own coordinator and
workers: much of a schedule is waiting (a deadline, a worker dialled again
every 0.5 s), so the two cores stay busy.

Usage: tests/hostile_run.py [--schedules 2000] [--seed S] [--engines a,b]
       [--batch 50] [--parallel 2] [--build build] [--out bench/results]
       [--only K]
"""
import argparse
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "integration"))

ENGINES = ["mrf", "fill", "aerial", "stylize", "patchmatch", "segment"]
# Short deadlines keep a stalled or silent worker's cost near 0.3 s; the
# heartbeat makes idle pings (H) frequent enough to damage.
SERVER_ARGS = ["--batch-timeout", "0.3", "--calibrate-ms", "20", "--heartbeat", "0.1", "--jobs", "1"]
JOB_TIMEOUT = 120

# ---- the engines' jobs ------------------------------------------------------


def make_scenes(data, d, build, engines):
    """The engines' small inputs, in d."""
    from pnm import oiiotool
    from collage import Source, TextureClass, band, build as collage, disk
    if "mrf" in engines:
        oiiotool(data / "textures/brick.png", "--cut", "160x160+0+0", "--origin", "+0+0", "-o", d / "ref.png")
    if "fill" in engines:
        oiiotool(data / "textures/brick.png", "--cut", "128x96+40+60", "--origin", "+0+0", "-o", d / "fill.png")
        oiiotool("--create", "128x96", "1", "--fill:color=1", "30x24+50+36", "-d", "uint8", "-o", d / "hole.png")
    if "aerial" in engines:
        subprocess.run([str(build / "bench/mkscene"), "--size", "128", "--seed", "7", "-o", str(d / "scene")],
                       check=True, capture_output=True)
        subprocess.run(["bash", str(REPO / "bench/aerial_refs.sh"), str(d)], check=True, capture_output=True)
    if "stylize" in engines or "patchmatch" in engines:
        oiiotool(data / "aerial/aero1.jpg", "--cut", "128x96+200+150", "--resize", "64x48", "-o", d / "style.png")
        oiiotool(d / "style.png", "--chsum:weight=.3,.59,.11", "--blur", "3x3", "-o", d / "src.png")
        oiiotool(d / "src.png", "--flop", "-o", d / "tgt.png")
    if "segment" in engines:
        aero = Source(data / "aerial/aero1.jpg")
        classes = [
            TextureClass("brick", 0, Source(data / "textures/brick.png", "200x200"), "64x64+0+0", "64x64+104+104"),
            TextureClass("grass", 1, Source(data / "textures/grass.png", "256x256"), "64x64+0+0", "80x80+128+128"),
            TextureClass("town", 2, aero, "64x64+110+105", "64x64+0+110"),
        ]
        seg = d / "segment"
        seg.mkdir(exist_ok=True)
        collage(classes, [1, (0, disk(0.3, 0.3, 0.25)), (2, band(0.1, 0.62, 0.9, 0.9))], 80, seg)


def job_args(engine, d, out):
    """The CLI arguments of engine's job on the scenes in d, writing
    out.png (and a side output where the engine has one); returns them and
    the output files."""
    png, raw = out.with_suffix(".png"), out.with_suffix(".raw")
    if engine == "mrf":
        return ["synth", "--ref", d / "ref.png", "--size", "128x96", "--levels", "3", "--usage-weight", "1",
                "-o", png, "--copy-map-raw", raw], [png, raw]
    if engine == "fill":
        return ["synth", "--input", d / "fill.png", "--mask", d / "hole.png", "--levels", "3", "-o", png,
                "--copy-map-raw", raw], [png, raw]
    if engine == "aerial":
        return ["aerial", "--classes", d / "scene-classes.png", "--catalogue", d / "catalogue.json", "-o", png], [png]
    if engine in ("stylize", "patchmatch"):
        search = "patchmatch" if engine == "patchmatch" else "exact"
        return ["stylize", "--style", d / "style.png", "--guide", d / "src.png", d / "tgt.png", "--iters", "3",
                "--search", search, "-o", png, "--nnf", raw], [png, raw]
    if engine == "segment":
        s = d / "segment"
        pairs = []
        for k in range(3):
            pairs += ["--train", s / f"train{k}.png", "--labels", s / f"labels{k}.png"]
        return ["segment", *pairs, "--input", s / "input.png", "--levels", "2", "--window", "7", "--denoise", "20",
                "-o", png], [png]
    raise ValueError(engine)


def cli(build, *args, timeout=JOB_TIMEOUT):
    return subprocess.run([str(build / "texsyn"), *map(str, args), "--quiet"], capture_output=True, text=True,
                          timeout=timeout)


# ---- schedules ----------------------------------------------------------------

REPLY_ACTIONS = ["dup", "reorder", "delay", "drop", "truncate", "cut-half", "forge", "cut", "kill", "stop"]
REQUEST_ACTIONS = ["kill-on-send", "stop-on-send", "cut-on-send"]
FORGE_TYPES = "IRVNGTQHCE"
FORGE_IDENTS = ["trigger", "oldest", "answered", "unsent", "random"]
FORGE_BODIES = ["plausible", "wrong-set", "wrong-gen", "wrong-nq", "out-of-slice", "out-of-set", "garbage"]
# Replies whose exchange waits 30 s or more for a missing answer (a slice
# or image load, a PatchMatch pass, a calibration): a dropped one is
# followed by a cut, or a schedule would wait that long.
LONG_WAIT = "CNRGTI"


def draw_rule(rng, counts):
    """One rule as a JSON-able dict, for a job whose fault-free run sees
    counts[(side, type)] frames."""
    replies = sorted(t for (side, t), n in counts.items() if side == "reply" and n > 0 and t not in "ICH")
    requests = sorted(t for (side, t), n in counts.items() if side == "request" and n > 0 and t not in "IC")
    action = rng.choice(REPLY_ACTIONS + REQUEST_ACTIONS + ["forge"] * 2 + ["stray-ack"] * 2)
    answers = [t for t in replies if t in "VT"]
    if action == "stray-ack" and answers:
        # Issue 25's first finding, generalised: an acknowledgement carrying
        # the id of the answer it precedes, which is then held a while.
        on = rng.choice(answers)
        return {"side": "reply", "on": on, "nth": rng.randint(1, counts["reply", on]), "action": "forge",
                "kind": "stray-ack", "place": "before", "hold": rng.choice([0.05, 0.2, 0.5]),
                "forge": {"type": rng.choice("RNGQH"), "ident": "trigger", "body": "plausible",
                          "seed": rng.randrange(1 << 30)}}
    if action == "stray-ack":
        action = "forge"
    if action in REQUEST_ACTIONS:
        on = rng.choice(requests)
        return {"side": "request", "on": on, "nth": rng.randint(1, max(1, counts["request", on])),
                "action": action.split("-")[0], "seconds": round(rng.uniform(0.1, 1.0), 2)}
    # A worker's 'I' and 'C' come when it joins, which a schedule forces
    # (a second), 'H' when it is idle (0.1 to 0.6 s): one schedule in six.
    on = rng.choice("ICH") if rng.random() < 1 / 6 else rng.choice(replies)
    n = counts["reply", on] if on not in "ICH" else 1
    rule = {"side": "reply", "on": on, "nth": rng.randint(1, max(1, n)), "action": action}
    if action == "delay":
        rule["ms"] = rng.choice([5, 20, 100, 250, 400, 800])
    elif action == "drop" and on in LONG_WAIT:
        rule["cut_after"] = 0.2
    elif action == "truncate":
        rule["keep"] = rng.randint(0, 40)
    elif action == "stop":
        rule["seconds"] = round(rng.uniform(0.1, 1.0), 2)
    elif action == "forge":
        ftype, ident, body = rng.choice(FORGE_TYPES), rng.choice(FORGE_IDENTS), rng.choice(FORGE_BODIES)
        # A well-formed answer to the very request it names is a lie no
        # check can catch: a content-bearing forgery names another frame or
        # carries a detectable flaw.
        if ftype in "VT" and ident in ("trigger", "oldest") and body == "plausible":
            body = rng.choice(FORGE_BODIES[1:])
        rule["forge"] = {"type": ftype, "ident": ident, "body": body, "seed": rng.randrange(1 << 30)}
        rule["place"] = rng.choice(["before", "after", "instead"])
        if rule["place"] == "before":
            rule["hold"] = rng.choice([0, 0.05, 0.2, 0.5])
    return rule


def draw_schedule(rng, counts):
    rules = [draw_rule(rng, counts)]
    if rng.random() < 0.2:
        rules.append(draw_rule(rng, counts))
    return rules


def label(rule):
    """The rule's action as the table's column."""
    a = rule["action"]
    if rule["side"] == "request":
        return f"{a}-on-send"
    if rule.get("kind") == "stray-ack":
        return "stray-ack"
    if a == "forge":
        return f"forge-{rule['place']}"
    return a


# ---- a batch: one coordinator, an honest worker, a hostile one ---------------

class Batch:
    def __init__(self, engine, root, build, scenes, pieces):
        from conftest import Daemon
        from hostile import HostileProxy
        self.Daemon, self.engine, self.build, self.scenes = Daemon, engine, build, scenes
        self.dir = Path(tempfile.mkdtemp(prefix=f"{engine}-", dir=root))
        self.pieces = pieces
        self.nworker = 0
        self.honest = self.worker()
        self.hostile = self.worker()
        self.hostiles = [self.hostile]
        self.hung = []
        self.proxy = HostileProxy(self.hostile.addr, self.hostile)
        self.server = Daemon([build / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", self.dir / "spool",
                              "--workers", f"{self.honest.addr},{self.proxy.addr}", *SERVER_ARGS],
                             self.dir / "server.log")
        self.jobs = 0

    def worker(self):
        self.nworker += 1
        extra = ["--max-frame", "4096"] if self.pieces and self.nworker > 1 else []
        return self.Daemon([self.build / "texsyn-worker", "--listen", "127.0.0.1:0", "--threads", "1", "--name",
                            f"w{self.nworker}", *extra], self.dir / f"worker{self.nworker}.log")

    def revive(self):
        """The hostile worker, alive and running (a stopped one continued, a
        dead one replaced behind the same proxy)."""
        self.hostile.proc.send_signal(signal.SIGCONT)
        if not self.hostile.alive():
            self.hostile.stop()
            self.hostile = self.worker()
            self.hostiles.append(self.hostile)
            self.proxy.retarget(self.hostile.addr, self.hostile)

    def ready(self, timeout=15):
        """Waits until both workers are ready (the hostile one revived if
        need be); False if they are not."""
        deadline = time.time() + timeout
        while time.time() < deadline:
            if not self.hostile.alive():
                self.revive()
            p = cli(self.build, "workers", "--server", self.server.addr, timeout=30)
            if p.returncode == 0 and p.stdout.count(" active ") >= 2:
                return True
            time.sleep(0.05)
        return False

    def history(self):
        """{id: (state, text)} of every job (`texsyn status`: under its
        header, id, state and seven more columns, then the text two spaces
        after the output's name)."""
        p = cli(self.build, "status", "--server", self.server.addr, timeout=30)
        jobs = {}
        for line in p.stdout.splitlines():
            f = line.split(None, 8)
            if len(f) == 9 and f[0].isdigit():
                assert int(f[0]) not in jobs, f"job {f[0]} listed twice"
                jobs[int(f[0])] = (f[1], f[8].partition("  ")[2].strip())
        return jobs

    def run(self, specs, want, counts):
        """One schedule: returns its record."""
        from hostile import Forge, Rule
        rec = {"engine": self.engine, "rules": specs}
        t0 = time.time()
        self.revive()
        if not self.ready():
            rec["outcome"], rec["why"] = "lost", "the pool did not come back to 2 ready workers"
            return rec
        rules = []
        for s in specs:
            p = {k: v for k, v in s.items() if k not in ("side", "on", "nth", "action", "forge", "kind")}
            if "forge" in s:
                f = s["forge"]
                p["forge"] = Forge(f["type"], f["ident"], f["body"], f["seed"])
            action = s["action"]
            if action == "cut-half":
                action, p["how"] = "truncate", "half"
            rules.append(Rule(s["on"], nth=s["nth"], action=action, side=s["side"], **p))
        log_at = len(self.server.read_log())
        self.proxy.arm(rules)
        joins = [r for r in rules if r.side == "reply" and r.on in "CI"]
        if joins:
            self.proxy.cut_all()  # the worker joins again: its 'I' and 'C' replies go through the rules
            for r in joins:
                r.fired.wait(3.0)  # dialled again within 0.5 s
            self.ready()
        for r in rules:
            if r.side == "reply" and r.on == "H":
                r.fired.wait(2.0)  # an idle worker is pinged every 0.1 s
        self.jobs += 1
        out = self.dir / f"out{self.jobs}"
        args, outputs = job_args(self.engine, self.scenes, out)
        try:
            p = cli(self.build, *args, "--server", self.server.addr)
            code, err = p.returncode, p.stderr.strip()
        except subprocess.TimeoutExpired:
            code, err = None, f"the client hung for {JOB_TIMEOUT} s"
        rec["fired"] = [r.fired.is_set() for r in rules]
        rec["events"] = self.proxy.events[:8]
        log = self.server.read_log()[log_at:]
        rec["dropped"] = [why for _, peer, why in _dropped(log) if peer == self.proxy.addr]
        rec["honest_dropped"] = [why for _, peer, why in _dropped(log) if peer == self.honest.addr]
        rec["seconds"] = round(time.time() - t0, 3)
        if rec["seconds"] > 5:  # what took long, for the report
            rec["log"] = log.splitlines()[-20:]
        if not self.server.alive():
            rec["outcome"], rec["why"] = "lost", "the coordinator died"
            return rec
        jobs = self.history()
        state, text = jobs.get(self.jobs, (None, ""))
        if sorted(jobs) != list(range(1, self.jobs + 1)):
            rec["outcome"], rec["why"] = "lost", f"the history holds jobs {sorted(jobs)}, not 1..{self.jobs}"
        elif code == 0 and state == "done":
            got = tuple(Path(o).read_bytes() for o in outputs)
            rec["outcome"] = "identical" if got == want else "different"
        elif code not in (0, None) and state == "failed" and text:
            rec["outcome"], rec["why"] = "failed", text
        else:
            rec["outcome"], rec["why"] = "lost", f"client exit {code} ({err[-300:]}), job state {state} {text!r}"
        for o in outputs:
            Path(o).unlink(missing_ok=True)
        return rec

    def close(self):
        # Disarmed first: a rule firing late would stop a worker after its
        # SIGCONT below, and it would not exit on SIGTERM.
        self.proxy.arm([])
        self.proxy.close()
        self.hung = []
        for d in (self.server, self.honest, *self.hostiles):
            if d.alive():
                d.proc.send_signal(signal.SIGCONT)
                d.proc.send_signal(signal.SIGTERM)
                try:
                    d.proc.wait(timeout=20)
                except subprocess.TimeoutExpired:  # what its threads are doing, for the report
                    self.hung.append(f"{d.name} (pid {d.proc.pid}) ignored SIGTERM: {threads_of(d.proc.pid)}")
            d.stop()

    def faults(self):
        return [f for d in (self.server, self.honest, *self.hostiles) for f in d.faults()] + self.hung


def _dropped(log):
    from hostile import dropped_lines
    return dropped_lines(log)


def threads_of(pid):
    """Each thread's state and kernel stack's top (/proc, as root)."""
    out = []
    for task in sorted(Path(f"/proc/{pid}/task").iterdir()):
        try:
            state = (task / "stat").read_text().rsplit(")", 1)[1].split()[0]
            stack = [line.split()[-1] for line in (task / "stack").read_text().splitlines()[:4]]
            out.append(f"{task.name} {state} {(task / 'wchan').read_text()} {'<'.join(stack)}")
        except OSError as e:
            out.append(f"{task.name} ({e.strerror})")
    return "; ".join(out)


def cpu_model():
    info = Path("/proc/cpuinfo").read_text()
    m = re.search(r"model name\s*:\s*(.*)", info)
    return m.group(1).strip() if m else "unknown", os.cpu_count()


# ---- the run ----------------------------------------------------------------------

def run_engine(e, ks, seed, want, counts, base_seconds, root, build, scenes, batch_size, out, progress):
    """Engine e's schedules ks, batch_size to a coordinator; records go to
    out["records"], the ones that must never happen also to out["problems"]."""
    nbatch = 0
    while ks:
        b = Batch(e, root, build, scenes, pieces=nbatch % 2 == 1)
        nbatch += 1
        try:
            if e not in counts:  # the frames of a fault-free job through the proxy
                rec = b.run([], want, None)
                assert rec["outcome"] == "identical", f"{e}: the fault-free job through the proxy: {rec}"
                counts[e], base_seconds[e] = Counter(b.proxy.counts), rec["seconds"]
            for _ in range(batch_size):
                if not ks:
                    break
                k = ks.pop(0)
                specs = draw_schedule(random.Random(f"{seed}:{k}"), counts[e])
                rec = b.run(specs, want, counts[e])
                rec["schedule"], rec["pieces"] = k, b.pieces
                if rec["outcome"] == "identical":
                    rec.pop("events", None)  # what the proxy did, kept where it matters
                out["records"].append(rec)
                if rec["outcome"] in ("different", "lost"):
                    out["problems"].append(rec)
                    progress(f"schedule {k} ({e}): {rec['outcome']}: {rec.get('why', '')} rules {specs}")
                done = len(out["records"])
                if done % 50 == 0:
                    progress(f"{done}/{out['planned']} schedules, {time.time() - out['t0']:.0f} s, "
                             f"{dict(Counter(r['outcome'] for r in out['records']))}")
                if not b.server.alive():
                    break  # a new coordinator for the rest
        finally:
            b.close()
            for f in b.faults():
                out["problems"].append({"engine": e, "outcome": "lost", "why": f})
                progress(f)


def run_schedules(n, seed, engines, build, data, batch_size=50, only=None, progress=print, workdir=None,
                  parallel=1):
    """Runs n schedules spread over the engines (schedule k on engine k mod
    len(engines)), `parallel` engines at a time; returns the result dict.
    The daemons' logs and files go to workdir, kept, or to a temporary
    directory removed at the end."""
    plan = [(k, engines[k % len(engines)]) for k in range(n)]
    if only is not None:
        plan = [plan[only]]
    engines = [e for e in engines if any(pe == e for _, pe in plan)]
    root = Path(workdir) if workdir is not None else Path(tempfile.mkdtemp(prefix="texsyn-hostile-"))
    t0 = time.time()
    out = {"records": [], "problems": [], "planned": len(plan), "t0": t0}
    want, counts, base_seconds = {}, {}, {}
    try:
        scenes = root / "scenes"
        scenes.mkdir()
        make_scenes(data, scenes, build, engines)
        for e in engines:
            args, outputs = job_args(e, scenes, root / f"embedded-{e}")
            p = cli(build, *args, "--embedded")
            assert p.returncode == 0, f"{e}: the embedded run failed: {p.stderr}"
            want[e] = tuple(Path(o).read_bytes() for o in outputs)
        todo = list(engines)
        failures = []

        def drain():
            while todo:
                e = todo.pop(0)
                try:
                    run_engine(e, [k for k, pe in plan if pe == e], seed, want[e], counts, base_seconds, root,
                               build, scenes, batch_size, out, progress)
                except Exception as x:  # reported after the others end
                    failures.append(x)

        threads = [threading.Thread(target=drain) for _ in range(max(1, parallel))]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        if failures:
            raise failures[0]
    finally:
        if workdir is None:
            shutil.rmtree(root, ignore_errors=True)
    elapsed = time.time() - t0
    records = sorted(out["records"], key=lambda r: r["schedule"])
    model, cores = cpu_model()
    spent = sum(r["seconds"] for r in records)
    commit = subprocess.run(["git", "-C", str(REPO), "describe", "--always", "--dirty"], capture_output=True,
                            text=True).stdout.strip()
    return {"seed": seed, "commit": commit, "cpu": model, "cores": cores, "parallel": parallel,
            "schedules": len(records), "seconds": round(elapsed, 1),
            "seconds_per_schedule": round(elapsed / max(1, len(records)), 3),
            "median_schedule_seconds": sorted(r["seconds"] for r in records)[len(records) // 2] if records else 0,
            "schedule_seconds": round(spent, 1), "fault_free_job_seconds": base_seconds,
            "frames_per_job": {e: {f"{s} {t}": c for (s, t), c in sorted(counts[e].items())} for e in counts},
            "outcomes": dict(Counter(r["outcome"] for r in records)), "problems": out["problems"],
            "records": records}


def rule_text(rule):
    """A rule in a few words, for the report."""
    what = label(rule)
    if "forge" in rule:
        f = rule["forge"]
        what += f" '{f['type']}' ({f['ident']} id, {f['body']})"
    return f"{what} on {rule['side']} '{rule['on']}' #{rule['nth']}"


def drop_reasons(records):
    """Why the hostile worker was dropped, addresses and numbers elided: counts."""
    reasons = Counter()
    for r in records:
        for why in r.get("dropped", []):
            why = re.sub(r"\d+\.\d+\.\d+\.\d+:\d+", "PEER", why)
            reasons[re.sub(r"\d+", "N", why)[:70]] += 1
    return dict(reasons.most_common())


def compact(result):
    """The result as written: one short line per schedule (its rules are
    drawn again from the seed), the problems and the slow schedules whole."""
    out = {k: v for k, v in result.items() if k != "records"}
    out["drop_reasons"] = drop_reasons(result["records"])
    out["slow"] = [r for r in result["records"] if r["seconds"] > 5][:50]
    out["per_schedule"] = [{"k": r["schedule"], "engine": r["engine"],
                            "action": label(r["rules"][0]) if r["rules"] else "none", "outcome": r["outcome"],
                            "s": r["seconds"], "fired": bool(r.get("fired") and r["fired"][0]),
                            "dropped": bool(r.get("dropped"))} for r in result["records"]]
    return out


def to_json(c):
    """compact(result) as text: a schedule a line."""
    head = {k: v for k, v in c.items() if k != "per_schedule"}
    lines = ",\n".join("  " + json.dumps(r, separators=(",", ":")) for r in c["per_schedule"])
    return json.dumps(head, indent=1)[:-2] + ',\n "per_schedule": [\n' + lines + "\n ]\n}\n"


def table(c):
    """The markdown report of compact(result): outcomes per action and engine."""
    cells = defaultdict(Counter)
    for r in c["per_schedule"]:
        for key in ((r["action"], r["engine"]), (r["action"], "all")):
            x = cells[key]
            x[r["outcome"]] += 1
            x["n"] += 1
            x["fired"] += r["fired"]
            x["dropped"] += r["dropped"]
            x["slow"] += r["s"] > 5
    result = c
    engines = [e for e in ENGINES if any(k[1] == e for k in cells)]
    actions = sorted({a for a, _ in cells})
    out = ["# Hostile-peer schedules (issue 25)", "",
           f"{result['schedules']} seeded schedules, seed {result['seed']} (replay: `tests/hostile_run.py --seed "
           f"{result['seed']}`), texsyn at {result['commit']}, {result['parallel']} engine(s) at a time: "
           f"{result['seconds']} s in all (setup included), {result['seconds_per_schedule']} s per schedule "
           f"(median {result['median_schedule_seconds']} s). CPU: {result['cpu']}, {result['cores']} cores.", "",
           "Outcomes: " + ", ".join(f"{k} {v}" for k, v in sorted(result["outcomes"].items())) + ".", "",
           "Each cell: identical / failed with a reason / **different** / **lost**. Rows: the schedule's first "
           "rule (a fifth of the schedules have a second). The last columns, over every engine: schedules, "
           "those whose trigger came, those where the hostile worker was dropped, those that took over 5 s.", "",
           "| action | " + " | ".join(engines) + " | all | n | fired | dropped | > 5 s |",
           "|---|" + "---|" * (len(engines) + 5)]
    for a in actions:
        row = []
        for e in engines + ["all"]:
            x = cells[a, e]
            row.append(f"{x['identical']}/{x['failed']}/{x['different']}/{x['lost']}" if x["n"] else "")
        t = cells[a, "all"]
        out.append(f"| {a} | " + " | ".join(row) + f" | {t['n']} | {t['fired']} | {t['dropped']} | {t['slow']} |")
    out += ["", "Why the hostile worker was dropped (numbers as N):", ""]
    out += [f"* {n} x {why}" for why, n in list(result["drop_reasons"].items())[:15]]
    if result["problems"]:
        out += ["", "Problems (different or lost):", ""]
        for p in result["problems"][:40]:
            rules = "; ".join(rule_text(r) for r in p.get("rules", []))
            out.append(f"* schedule {p.get('schedule', '-')} ({p['engine']}): {p['outcome']}"
                       + (f": {p['why']}" if p.get("why") else "") + (f" - {rules}" if rules else ""))
    return "\n".join(out) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--schedules", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=None)
    ap.add_argument("--engines", default=",".join(ENGINES))
    ap.add_argument("--batch", type=int, default=50, help="schedules per coordinator")
    ap.add_argument("--parallel", type=int, default=2, help="engines run at once, each with its coordinator")
    ap.add_argument("--only", type=int, default=None, help="replay schedule K of the seed's run only")
    ap.add_argument("--table", default=None, help="only write the report of this results JSON again")
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default=str(REPO / "bench" / "results"))
    a = ap.parse_args()
    if a.table is not None:
        c = json.loads(Path(a.table).read_text())
        if "records" in c:  # a whole result, as run_schedules returns it
            c = compact(c)
            Path(a.table).write_text(to_json(c))
        (Path(a.table).parent / "hostile.md").write_text(table(c))
        return 0
    build = Path(a.build).resolve()
    os.environ["TEXSYN_BUILD"] = str(build)
    data = Path(os.environ.get("TEXSYN_DATA") or subprocess.run(["bash", str(REPO / "tests/test-data.sh")],
                                                                capture_output=True, text=True).stdout.strip())
    seed = a.seed if a.seed is not None else int.from_bytes(os.urandom(4), "little")
    print(f"hostile schedules: seed {seed} (replay with --seed {seed})", flush=True)
    engines = a.engines.split(",")
    result = run_schedules(a.schedules, seed, engines, build, data, a.batch, a.only,
                           progress=lambda s: print(s, flush=True), parallel=a.parallel)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    c = compact(result)
    if a.only is None:
        (out / "hostile.json").write_text(to_json(c))
        (out / "hostile.md").write_text(table(c))
    print(table(c))
    bad = result["outcomes"].get("different", 0) + result["outcomes"].get("lost", 0) + \
        sum(1 for p in result["problems"] if "schedule" not in p)
    print(f"seed {seed}: {result['outcomes']}; {bad} problem(s)")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
