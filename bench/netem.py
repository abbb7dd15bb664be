#!/usr/bin/python3
"""Cluster scaling under network latency, and a fitted performance model.

The coordinator and its workers run in two network namespaces joined by a
veth pair (tests/integration/netns.py with one worker slot: 10.78.0.1
coordinator side, 10.78.0.2 worker side), so every byte between them
crosses an interface. A round-trip time (RTT) is added
between them:
  netem   `tc qdisc ... netem delay RTT/2` on both ends of the veth, where
          the kernel has the netem qdisc;
  relay   otherwise: bench/delay_relay (built into BUILD/bench/), one per
          coordinator, in the coordinator's namespace; the workers --join
          it and it holds every chunk RTT/2 in each direction before
          forwarding it to the coordinator. It runs at SCHED_FIFO so its
          timers end on time while the workers keep the cores busy.
The RTT added is verified independently: small request/response round
trips from the workers' namespace to an echo server in the coordinator's
(through a relay in relay mode; ping as well under netem), and in relay
mode each run's relay reports the one-way delay it achieved on the job's
own traffic.

Series: RTT 0, 50, 200, 1000 us x 1 and 2 workers (1 scan thread each) x
two batching settings: the default (--pipeline-queries 256, and the
engine's wavefront batches) and small frames (--pipeline-queries 8).
Runs are interleaved (every rep runs every RTT and configuration once),
medians of --reps (3) with the spread (min-max). The job: the seed's
Table 3.3 job with parity (brick 512^2 -> 1024^2, L=5, W_N=7, W_B=3);
--quick: a 512x512 output. Time is the engine's (the report's per-level
seconds summed: upload and download between the client and the
coordinator, local here, are left out); throughput = queries (blocks
searched) per second; efficiency = throughput / the same configuration's
throughput at 0 us. Every output must equal the embedded run's bytes.

The model, fitted per pyramid level by least squares (pure Python):
  T_l = s*Q_l + c*P_l/N + R_l*(RTT + t_rt) + b*B_l
Q_l queries, P_l comparisons, R_l round trips (engine batches) and B_l
wire bytes from the level's report, N workers. s: the coordinator's
serial work per query, c: a worker's time per comparison, t_rt: fixed
cost per round trip, b: time per byte on the wire (the inverse of an
effective bandwidth, the coordinator's handling of the bytes included).
Validation: fitted without the 200 us points, which it then predicts.
Predictions for 16 and 64 workers (one core each) and for an unbatched
engine (one round trip per query).

Needs root (namespaces, tc, SCHED_FIFO). Removes its namespaces on exit,
also on failure or SIGTERM. Writes netem-runs.json (every run), then
netem.json, netem.md, netem.gp and netem.png into --out; --analyse
netem-runs.json redoes the second part without measuring.
"""
import argparse
import atexit
import json
import math
import os
import re
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "integration"))
import netns  # noqa: E402  (the namespaces the partition tests and the soak use too)

DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
RTTS_US = [0, 50, 200, 1000]
WORKERS = [1, 2]
BATCHING = {"default": 256, "small": 8}  # --pipeline-queries
JOB = ["--levels", 5, "--wn", 7, "--wb", 3, "--parity", "--quiet"]
NET = netns.Net(1, tag=f"tsn{os.getpid() % 100000}")  # the coordinator's namespace and one worker slot
NS_C, NS_W = NET.coord_ns, NET.worker_ns(0)
COORD_IP, WORKER_IP = NET.coord_ip(0), NET.worker_ip(0)
DEV = {NS_C: NET.coord_dev(0), NS_W: NET.worker_dev(0)}  # each namespace's end of the veth
PREDICT_N = [16, 64]
VALIDATE_RTT = 200

# Small request/response probes for the RTT check, run inside the
# namespaces: an echo server (prints its port) and a client that times
# N round trips of 32 bytes to HOST:PORT (prints the seconds as JSON).
ECHO = """
import socket, sys, threading
ls = socket.socket(); ls.bind((sys.argv[1], 0)); ls.listen(16)
print(ls.getsockname()[1], flush=True)
def serve(c):
    c.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    while True:
        b = c.recv(4096)
        if not b:
            return
        c.sendall(b)
while True:
    c, _ = ls.accept()
    threading.Thread(target=serve, args=(c,), daemon=True).start()
"""
PROBE = """
import json, socket, sys, time
host, port, n = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
s = socket.create_connection((host, port)); s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
out = []
for i in range(n):
    t = time.perf_counter(); s.sendall(b"x" * 32); got = b""
    while len(got) < 32:
        got += s.recv(32 - len(got))
    out.append(time.perf_counter() - t)
print(json.dumps(out[5:]))
"""


def sh(*args, check=True):
    p = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if check and p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, args))}: {p.stderr.strip()}")
    return p


def in_ns(ns, *args):
    return ["ip", "netns", "exec", ns, *[str(a) for a in args]]


# ---- namespaces ----------------------------------------------------------------

class Topology:
    """Two namespaces and the veth between them; removed by close()."""

    def __init__(self):
        self.up = False

    def create(self):
        self.up = True
        NET.create(partitions=False)

    def try_netem(self):
        """Adds a 0 us netem qdisc on both veth ends; the error when the
        kernel cannot (None when it can)."""
        for ns in (NS_C, NS_W):
            p = sh("ip", "netns", "exec", ns, "tc", "qdisc", "add", "dev", DEV[ns], "root", "netem", "delay", "0us",
                   check=False)
            if p.returncode != 0:
                return p.stderr.strip() or f"tc exited {p.returncode}"
        return None

    def set_netem(self, rtt_us):
        for ns in (NS_C, NS_W):
            sh("ip", "netns", "exec", ns, "tc", "qdisc", "change", "dev", DEV[ns], "root", "netem", "delay",
               f"{rtt_us / 2}us")

    def close(self):
        if self.up:
            NET.close()  # the veth goes with the namespaces
            self.up = False


class Procs:
    """Every process started, stopped in reverse order on close()."""

    def __init__(self):
        self.all = []

    def start(self, args, log, stdin=None, want_line=True):
        p = subprocess.Popen([str(a) for a in args], stdin=stdin, stdout=subprocess.PIPE,
                             stderr=open(log, "w"), text=True)
        self.all.append(p)
        if not want_line:
            return p, None
        line = p.stdout.readline()
        m = re.search(r"listening on (\S+)", line) or re.match(r"(\d+)$", line.strip())
        if not m:
            raise RuntimeError(f"{args[4] if args[0] == 'ip' else args[0]} did not start, see {log}")
        return p, m.group(1)

    def close(self):
        for p in reversed(self.all):
            if p.poll() is None:
                p.terminate()
        for p in reversed(self.all):
            try:
                p.wait(timeout=30)
            except subprocess.TimeoutExpired:
                p.kill()
        self.all = []


# ---- the cluster configurations ---------------------------------------------------

class Config:
    def __init__(self, n, batching):
        self.n, self.batching = n, batching
        self.label = f"{n} worker{'s' if n > 1 else ''}, {batching} batching"
        self.key = f"w{n}-{batching}"
        self.relay = None
        self.addr = None  # the coordinator, for clients (in its namespace)
        self.pids = {}  # role -> pids, for their CPU time

    def up(self, build, tmp, procs, secret, relay_mode):
        bind = "127.0.0.1" if relay_mode else COORD_IP
        server, self.addr = procs.start(in_ns(NS_C, build / "texsyn-server", "--listen", f"{bind}:0", "--spool",
                                         tmp / f"spool-{self.key}", "--threads", 1, "--secret-file", secret,
                                         "--pipeline-queries", BATCHING[self.batching]),
                                   tmp / f"{self.key}-server.log")
        self.pids = {"coordinator": [server.pid], "workers": [], "relay": []}
        join = self.addr
        if relay_mode:
            self.relay, join = procs.start(in_ns(NS_C, build / "bench" / "delay_relay", "--listen", f"{COORD_IP}:0",
                                                 "--target", self.addr, "--fifo"),
                                           tmp / f"{self.key}-relay.log", stdin=subprocess.PIPE)
            self.pids["relay"] = [self.relay.pid]
        for i in range(self.n):
            w, _ = procs.start(in_ns(NS_W, build / "texsyn-worker", "--join", join, "--threads", 1, "--secret-file", secret),
                        tmp / f"{self.key}-w{i}.log", want_line=False)
            self.pids["workers"].append(w.pid)  # `ip netns exec` execs the program: same pid
        wait_ready(build, self.addr, self.n)

    def cpu(self):
        """CPU seconds used so far per role (user + system, all threads)."""
        return {role: sum(cpu_seconds(p) for p in pids) for role, pids in self.pids.items()}

    def relay_command(self, line):
        self.relay.stdin.write(line + "\n")
        self.relay.stdin.flush()
        return self.relay.stdout.readline().strip()


def cpu_seconds(pid):
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def wait_ready(build, addr, n):
    for _ in range(1200):
        out = sh(*in_ns(NS_C, build / "texsyn", "workers", "--server", addr), check=False).stdout
        if out.count(" active ") >= n:
            return
        time.sleep(0.05)
    raise RuntimeError(f"{n} workers not ready at {addr}")


def synth(build, args, tmp, name, ns=True):
    out, rep = tmp / f"{name}.png", tmp / f"{name}.json"
    cmd = [build / "texsyn", "synth", *args, "-o", out, "--report", rep]
    t0 = time.monotonic()
    p = sh(*(in_ns(NS_C, *cmd) if ns else cmd), check=False)
    wall = time.monotonic() - t0
    if p.returncode != 0:
        raise RuntimeError(f"{name}: texsyn synth failed:\n{p.stderr}")
    return wall, json.loads(rep.read_text()), out


def levels_of(report):
    return [{"level": l["level"], "Q": l["blocks"], "P": l["comparisons"], "R": l["round_trips"],
             "B": l["wire_bytes"], "T": l["seconds"]} for l in report["levels"]]


# ---- RTT verification ----------------------------------------------------------------

def probe_rtts(target_ip, port, n=200):
    """Median and p99 (us) of small round trips from the worker namespace."""
    p = sh(*in_ns(NS_W, sys.executable, "-c", PROBE, target_ip, port, n))
    rtts = sorted(json.loads(p.stdout))
    return {"median_us": 1e6 * statistics.median(rtts), "p99_us": 1e6 * rtts[int(0.99 * (len(rtts) - 1))]}


def ping_rtt(n=50):
    p = sh(*in_ns(NS_W, "ping", "-c", n, "-i", "0.01", "-q", COORD_IP), check=False)
    m = re.search(r"= ([\d.]+)/([\d.]+)/([\d.]+)", p.stdout)
    return {"avg_us": 1000 * float(m.group(2)), "min_us": 1000 * float(m.group(1))} if m else None


def verify(build, tmp, procs, rtts, relay_mode, topo):
    """The added RTT per setting, measured by small round trips that
    cross the veth (and the relay, in relay mode)."""
    _, port = procs.start(in_ns(NS_C, sys.executable, "-c", ECHO, "0.0.0.0"), tmp / "echo.log")
    relay = None
    if relay_mode:
        relay, raddr = procs.start(in_ns(NS_C, build / "bench" / "delay_relay", "--listen", f"{COORD_IP}:0",
                                         "--target", f"127.0.0.1:{port}", "--fifo"),
                                   tmp / "probe-relay.log", stdin=subprocess.PIPE)
        port = raddr.rsplit(":", 1)[1]
    def measure_at(rtt, hold):
        if relay_mode:
            relay.stdin.write(f"delay {hold}\n")
            relay.stdin.flush()
            relay.stdout.readline()
        else:
            topo.set_netem(rtt)
        m = probe_rtts(COORD_IP, port)
        if not relay_mode:
            m["ping"] = ping_rtt()
        return m

    out = {}
    base = None
    for rtt in rtts:
        hold = rtt / 2
        m = measure_at(rtt, hold)
        base = m["median_us"] if base is None else base
        # The relay's timer and the idle peers' wake-ups add to its hold:
        # calibrate the hold so the probes see the RTT asked (a few steps of
        # the error's half; a target below what the wake-ups cost alone
        # stays above it, and the tables say so).
        for _ in range(4 if relay_mode and rtt > 0 else 0):
            err = (m["median_us"] - base) - rtt
            if abs(err) <= max(10.0, 0.05 * rtt) or (hold <= 1 and err > 0):
                break
            hold = max(1.0, hold - err / 2)
            m = measure_at(rtt, hold)
        m["hold_us"] = hold if relay_mode else None
        m["added_us"] = m["median_us"] - base
        out[rtt] = m
    return out


# ---- the model ------------------------------------------------------------------------

TERMS = ["s", "c", "t_rt"]  # fitted on wall time; b comes from the coordinator's CPU time


def features(lv, n, rtt_s, b):
    """The model's columns for one level, and its time less the terms
    known already: the RTT's (its coefficient is 1: a round trip waits
    one RTT) and the bytes' (b from the coordinator's CPU time)."""
    return [lv["Q"], lv["P"] / n, lv["R"]], lv["T"] - lv["R"] * rtt_s - b * lv["B"]


def solve(a, y, weight):
    """Weighted least squares by the normal equations, Gaussian elimination
    with partial pivoting, the columns scaled first (they differ by 10^9)."""
    k = len(a[0])
    m = [[0.0] * (k + 1) for _ in range(k)]
    for cols, target, w in zip(a, y, weight):
        for i in range(k):
            for j in range(k):
                m[i][j] += w * cols[i] * cols[j]
            m[i][k] += w * cols[i] * target
    scale = [math.sqrt(m[i][i]) or 1.0 for i in range(k)]
    for i in range(k):
        for j in range(k):
            m[i][j] /= scale[i] * scale[j]
        m[i][k] /= scale[i]
    for col in range(k):
        piv = max(range(col, k), key=lambda r: abs(m[r][col]))
        m[col], m[piv] = m[piv], m[col]
        if abs(m[col][col]) < 1e-12:
            raise RuntimeError("the model's terms cannot be told apart from these points")
        for r in range(k):
            if r != col:
                f = m[r][col] / m[col][col]
                m[r] = [x - f * z for x, z in zip(m[r], m[col])]
    return [m[i][k] / m[i][i] / scale[i] for i in range(k)]


def fit_bytes(rows):
    """The coordinator's CPU seconds per run against its wire bytes:
    cpu = a + b*B, least squares over the default-batching runs of every
    worker count and RTT (the queries and round trips are the same in
    every run, so a holds their part; small frames would fold their extra
    system calls into b). b is what a byte on the wire costs the
    coordinator, which handles every worker's frames in turn. CPU time,
    unlike wall time, hardly moves with other load on the machine."""
    pts = [(r["wire_bytes"], c) for r in rows if r["batching"] == "default" for c in r["cpu_coordinator_s"]]
    a, b = solve([[1.0, x] for x, _ in pts], [y for _, y in pts], [1.0] * len(pts))
    return {"a": a, "b": max(b, 0.0)}


def fit(points, b):
    """points: (levels, n, rtt_s) per measured configuration and RTT.
    Residuals weighted by 1/sqrt(T): a level's noise grows with its
    length, and the short coarse levels still count (they carry the round
    trips: few queries per step). No parameter may be negative (a time
    per query, comparison or round trip): one that comes out negative is
    set to 0 and the others fitted again, the most negative first."""
    rows, ys, ws = [], [], []
    for levels, n, rtt_s in points:
        for lv in levels:
            if lv["T"] <= 0:
                continue  # too short to time
            cols, y = features(lv, n, rtt_s, b)
            rows.append(cols)
            ys.append(y)
            ws.append(1.0 / lv["T"])
    free = list(range(len(TERMS)))
    while True:
        x = solve([[r[i] for i in free] for r in rows], ys, ws)
        if min(x) >= 0:
            break
        free.pop(x.index(min(x)))
    p = dict.fromkeys(TERMS, 0.0)
    p.update({TERMS[i]: v for i, v in zip(free, x)})
    p["clamped"] = [t for i, t in enumerate(TERMS) if i not in free]
    p["b"] = b
    return p


def predict(p, levels, n, rtt_s):
    return sum(p["s"] * lv["Q"] + p["c"] * lv["P"] / n + lv["R"] * (rtt_s + p["t_rt"]) + p["b"] * lv["B"]
               for lv in levels)


def scaled_levels(levels1, n, unbatched=False):
    """A job's levels on n workers, from its 1-worker report: comparisons
    are the same, wire bytes grow with the worker count (every worker gets
    every query and answers it), and an unbatched engine makes one round
    trip per query."""
    return [dict(lv, B=lv["B"] * n, R=lv["Q"] if unbatched else lv["R"]) for lv in levels1]


# ---- the experiment --------------------------------------------------------------------

def machine():
    info = Path("/proc/cpuinfo").read_text()
    get = lambda k: (re.search(rf"^{k}\s*:\s*(.*)$", info, re.M) or [None, "?"])[1]
    return {"cpu": get("model name"), "family": get("cpu family"), "model": get("model"), "cores": os.cpu_count(),
            "kernel": os.uname().release}


def run_series(a, build, tmp, topo, procs):
    method, why = "netem", None
    why = topo.try_netem()
    if why is not None or a.method == "relay":
        method = "relay"
        why = why or "--method relay"
    relay_mode = method == "relay"
    print(f"netem: delay by {method}" + (f" ({why})" if why else ""), flush=True)
    secret = tmp / "secret"
    secret.write_text(os.urandom(16).hex())
    secret.chmod(0o600)
    os.environ["TEXSYN_SECRET_FILE"] = str(secret)
    job = ["--ref", DATA / "textures" / "brick.png", "--size", "512x512" if a.quick else "1024x1024", *JOB]
    _, emb_report, emb_out = synth(build, [*job, "--embedded", "--threads", 2], tmp, "embedded", ns=False)
    verified = verify(build, tmp, procs, a.rtts, relay_mode, topo)
    configs = [Config(n, b) for n in WORKERS for b in BATCHING]
    for c in configs:
        c.up(build, tmp, procs, secret, relay_mode)
    runs = {(c.key, r): [] for c in configs for r in a.rtts}
    for rep in range(a.reps):
        for rtt in a.rtts:
            if relay_mode:
                for c in configs:
                    c.relay_command(f"delay {verified[rtt]['hold_us']}")
            else:
                topo.set_netem(rtt)
            for c in (configs if rep % 2 == 0 else configs[::-1]):  # ABBA over the configurations
                if relay_mode:
                    c.relay_command("stats")  # resets: what follows is this run's
                cpu0 = c.cpu()
                wall, report, out = synth(build, [*job, "--server", c.addr], tmp, f"{c.key}-{rtt}-{rep}")
                cpu = {k: v - cpu0[k] for k, v in c.cpu().items()}
                same = sh("cmp", "-s", out, emb_out, check=False).returncode == 0
                relay = json.loads(c.relay_command("stats")) if relay_mode else None
                lv = levels_of(report)
                runs[(c.key, rtt)].append({"wall_s": wall, "engine_s": sum(l["T"] for l in lv), "levels": lv,
                                           "identical": same, "relay": relay, "cpu_s": cpu})
                print(f"  rep {rep} rtt {rtt:5} us {c.label:28s} {sum(l['T'] for l in lv):7.3f} s"
                      f"{'' if same else '  OUTPUT DIFFERS'}", flush=True)
    return method, why, verified, configs, runs, emb_report


def added_rtt_us(rtt, verified):
    """The RTT a round trip of the job actually gained: the probes' added
    median (request/response across the veth, through a relay in relay
    mode). Under the relay it exceeds twice the relay's own hold time by
    the wake-ups of peers that went idle while waiting, as the job's
    round trips do (the per-level table shows it)."""
    return verified[rtt]["added_us"] if rtt else 0.0


def relay_hold_rtt_us(runs):
    """Twice the median one-way hold time the relay achieved on the runs'
    own traffic (None under netem)."""
    ones = [r["relay"]["median_us"] for r in runs if r["relay"] and r["relay"]["chunks"]]
    return 2 * statistics.median(ones) if ones else None


def summarise(configs, runs, rtts, verified):
    rows = []
    for c in configs:
        base = statistics.median(r["engine_s"] for r in runs[(c.key, rtts[0])])
        for rtt in rtts:
            rs = runs[(c.key, rtt)]
            q = sum(l["Q"] for l in rs[0]["levels"])
            secs = [r["engine_s"] for r in rs]
            med = statistics.median(secs)
            rows.append({
                "config": c.key, "label": c.label, "workers": c.n, "batching": c.batching,
                "pipeline_queries": BATCHING[c.batching], "rtt_us": rtt,
                "achieved_rtt_us": added_rtt_us(rtt, verified),
                "relay_hold_rtt_us": relay_hold_rtt_us(rs),
                "relay_p99_one_way_us": max((r["relay"]["p99_us"] for r in rs if r["relay"]), default=None),
                "median_s": med, "min_s": min(secs), "max_s": max(secs), "runs_s": secs,
                "wall_median_s": statistics.median(r["wall_s"] for r in rs),
                "queries": q, "throughput_qps": q / med, "efficiency": base / med,
                "round_trips": sum(l["R"] for l in rs[0]["levels"]),
                "wire_bytes": sum(l["B"] for l in rs[0]["levels"]),
                "identical": all(r["identical"] for r in rs),
                "levels": median_levels(rs),
                "cpu_coordinator_s": [r["cpu_s"]["coordinator"] for r in rs],
                "cpu_workers_median_s": statistics.median(r["cpu_s"]["workers"] for r in rs),
                "cpu_relay_median_s": statistics.median(r["cpu_s"]["relay"] for r in rs),
                "worker_cpu_per_comparison_ns": 1e9 * statistics.median(r["cpu_s"]["workers"] for r in rs) /
                sum(l["P"] for l in rs[0]["levels"]),
            })
    return rows


def median_levels(rs):
    out = []
    for i, lv in enumerate(rs[0]["levels"]):
        out.append(dict(lv, T=statistics.median(r["levels"][i]["T"] for r in rs)))
    return out


def model(rows, rtts):
    cpu = fit_bytes(rows)
    pts = lambda keep: [(r["levels"], r["workers"], r["achieved_rtt_us"] * 1e-6) for r in rows if keep(r)]
    full = fit(pts(lambda r: True), cpu["b"])
    held = fit(pts(lambda r: r["rtt_us"] != VALIDATE_RTT), cpu["b"]) \
        if VALIDATE_RTT in rtts and len(rtts) > 2 else None
    full["coordinator_cpu_intercept"] = cpu["a"]
    for r in rows:
        rtt_s = r["achieved_rtt_us"] * 1e-6
        r["model_s"] = predict(full, r["levels"], r["workers"], rtt_s)
        r["residual"] = (r["model_s"] - r["median_s"]) / r["median_s"]
        if held is not None:
            r["heldout_model_s"] = predict(held, r["levels"], r["workers"], rtt_s)
            r["heldout_error"] = (r["heldout_model_s"] - r["median_s"]) / r["median_s"]
    return full, held


def predictions(p, rows, rtts):
    """Throughput and efficiency for PREDICT_N workers at each RTT, from
    the 1-worker default-batching levels, batched and unbatched."""
    base = next(r for r in rows if r["workers"] == 1 and r["batching"] == "default" and r["rtt_us"] == rtts[0])
    q = base["queries"]
    out = []
    for unbatched in (False, True):
        for n in [1, 2, *PREDICT_N]:
            lv = scaled_levels(base["levels"], n, unbatched)
            t0 = predict(p, lv, n, 0.0)
            for rtt in rtts:
                t = predict(p, lv, n, rtt * 1e-6)
                terms = term_split(p, lv, n, rtt * 1e-6)
                out.append({"workers": n, "engine": "unbatched" if unbatched else "batched", "rtt_us": rtt,
                            "seconds": t, "throughput_qps": q / t, "efficiency": t0 / t,
                            "speedup_vs_1": None, "terms_s": terms})
    for r in out:
        one = next(x for x in out if x["workers"] == 1 and x["engine"] == r["engine"] and x["rtt_us"] == r["rtt_us"])
        r["speedup_vs_1"] = one["seconds"] / r["seconds"]
    return out


def term_split(p, lv, n, rtt_s):
    return {"serial": sum(p["s"] * l["Q"] for l in lv), "compute": sum(p["c"] * l["P"] / n for l in lv),
            "rtt": sum(l["R"] * rtt_s for l in lv), "per_round_trip": sum(l["R"] * p["t_rt"] for l in lv),
            "bytes": sum(p["b"] * l["B"] for l in lv)}


# ---- output -------------------------------------------------------------------------------

def plot(out, rows, curves, rtts):
    """netem.png: measured efficiency against RTT per workers x batching
    (solid, points), the model's (dashed) for them and for 16 and 64
    workers. Kept in one function for bench/gnuplot.py to take over."""
    grid = [rtts[0] + (rtts[-1] - rtts[0]) * i / 50 for i in range(51)]
    colour = {1: "#1f77b4", 2: "#d62728", 16: "#2ca02c", 64: "#9467bd"}
    blocks, cmds = [], []
    for key in dict.fromkeys(r["config"] for r in rows):
        rs = [r for r in rows if r["config"] == key]
        base = rs[0]["median_s"]  # the 0 us row: efficiency spread from its median over each run's time
        blocks.append("\n".join(f"{r['achieved_rtt_us']} {r['efficiency']} {base / r['max_s']} {base / r['min_s']}"
                                for r in rs))
        style = "pt 7" if rs[0]["batching"] == "default" else "pt 4 dt 3"
        cmds.append(f"$d{len(blocks) - 1} using 1:2:3:4 with yerrorlines lw 2 {style} "
                    f"lc rgb '{colour[rs[0]['workers']]}' title '{rs[0]['label']} (measured)'")
    for n, eng in [(1, "batched"), (2, "batched"), (16, "batched"), (64, "batched"), (64, "unbatched")]:
        eff = curves[(n, eng)]
        blocks.append("\n".join(f"{x} {eff(x)}" for x in grid))
        cmds.append(f"$d{len(blocks) - 1} using 1:2 with lines dt {2 if eng == 'batched' else 4} lw 2 "
                    f"lc rgb '{colour[n]}' title 'model: {n} worker{'s' if n > 1 else ''}, {eng}'")
    gp = ["set terminal pngcairo size 1100,560 font ',10'", "set output 'netem.png'",
          "set title 'Table 3.3 job: efficiency against added round-trip time'",
          "set xlabel 'added RTT (us)'", "set ylabel 'throughput / throughput at 0 us'",
          "set yrange [0:*]", f"set xrange [0:{rtts[-1] * 1.1}]", "set key outside right", "set grid"]
    for i, b in enumerate(blocks):
        gp += [f"$d{i} << EOD", b, "EOD"]
    gp.append("plot " + ", \\\n     ".join(cmds))
    (out / "netem.gp").write_text("\n".join(gp) + "\n")
    p = subprocess.run(["gnuplot", "netem.gp"], cwd=out, capture_output=True, text=True)
    if p.returncode != 0:
        print(f"netem: gnuplot failed, no plot: {p.stderr.strip()}")


def curve(p, rows, n, unbatched):
    base = next(r for r in rows if r["workers"] == 1 and r["batching"] == "default" and r["rtt_us"] == 0)
    lv = scaled_levels(base["levels"], n, unbatched)
    t0 = predict(p, lv, n, 0.0)
    return lambda rtt_us: t0 / predict(p, lv, n, rtt_us * 1e-6)


def markdown(raw, verified, rows, full, held, preds):
    info, method, why = raw["machine"], raw["method"], raw["why"]
    job = "512x512" if raw["quick"] else "1024x1024"
    L = [f"# Cluster efficiency under network latency ({'quick, ' if raw['quick'] else ''}{job} output)", "",
         f"Machine: {info['cpu']} (family {info['family']}, model {info['model']}), {info['cores']} cores, "
         f"kernel {info['kernel']}; load average {info['load_start']:.1f} at the start, {info['load_end']:.1f} at the "
         "end.", ""]
    busy = max(info["load_start"], info["load_end"]) > 0.5 * info["cores"] + 2  # ours: ~2 busy processes
    if busy:
        L += ["**Measured while other work kept the machine busy**: the wall times, hence the efficiencies "
              "and the wall-time fit, carry that load's noise (see the min-max spreads); the CPU times "
              "(coordinator, workers, relay) hardly move with it. Rerun on a quiet machine for final figures.", ""]
    L += [
         "## Method", "",
         "Coordinator and workers in two network namespaces joined by a veth pair (10.77.0.1, 10.77.0.2): "
         "every byte between them crosses an interface."]
    if method == "netem":
        L.append("The RTT is added by `tc qdisc netem delay RTT/2` on both veth ends.")
    else:
        L += [f"The kernel has no netem qdisc (`tc qdisc add ... netem` said: \"{why}\"), so the delay is "
              "added by `bench/delay_relay`: one relay per coordinator in the coordinator's namespace, the "
              "workers `--join` it, and it holds every chunk RTT/2 in each direction (epoll_pwait2 timeouts, "
              "1 ns timer slack, SCHED_FIFO, no busy-waiting). The RTT used below (model, plot) is "
              "the probes' added RTT below (it includes the wake-ups of peers idle while they wait, 0-80 us more "
              "than twice the relay's own hold time, which the tables give too)."]
    L += ["", f"Job: `texsyn synth --ref brick.png --size {job} {' '.join(map(str, JOB[:-1]))}` (the seed's "
          "Table 3.3 job), on 1 or 2 `texsyn-worker --threads 1`. Batching `default`: the coordinator's "
          f"`--pipeline-queries {BATCHING['default']}`; `small`: `--pipeline-queries {BATCHING['small']}`. "
          f"Time: the engine's seconds (the report's levels), median of {raw['reps']} runs interleaved over "
          "every RTT and configuration (spread: min-max). Throughput: queries (blocks searched) per second. "
          "Efficiency: throughput over the same configuration's at 0 us.", "",
          "### The added RTT, verified", "",
          "Small request/response round trips (32 bytes, TCP_NODELAY) from the workers' namespace to an echo "
          "server in the coordinator's" + (", through a relay" if method == "relay" else "") +
          "; added = median less the 0 us median." + (" Ping across the veth too." if method == "netem" else
          " The relay's one-way hold is calibrated per setting so that the probes' added RTT is the one asked "
          "(its timer and the idle peers' wake-ups add to the hold; a target below their cost stays above it)."),
          "", "| RTT asked (us) | probe median (us) | probe p99 (us) | added (us) |" +
          (" ping avg (us) |" if method == "netem" else " relay hold set, one way (us) |"),
          "|---|---|---|---|---|"]
    for rtt, v in verified.items():
        ping = f" {v['ping']['avg_us']:.0f} |" if method == "netem" and v.get("ping") else ""
        hold = f" {v['hold_us']:.1f} |" if v.get("hold_us") is not None else (" - |" if method != "netem" else "")
        L.append(f"| {rtt} | {v['median_us']:.0f} | {v['p99_us']:.0f} | {v['added_us']:.0f} |{ping}{hold}")
    L += ["", "## Results", "",
          "RTT added: the probes' (above); relay hold: twice the relay's median one-way hold on the run's own "
          "traffic.", "",
          "| configuration | RTT asked (us) | RTT added (us) | relay hold (us) | median s (min-max) | queries/s | "
          "efficiency | round trips | wire bytes | model s (residual) | model without 200 us (error) | "
          "output = embedded |",
          "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ho = f"{r['heldout_model_s']:.3f} ({100 * r['heldout_error']:+.1f} %)" if "heldout_model_s" in r else "-"
        hold = "-" if r["relay_hold_rtt_us"] is None else f"{r['relay_hold_rtt_us']:.0f}"
        L.append(f"| {r['label']} | {r['rtt_us']} | {r['achieved_rtt_us']:.0f} | {hold} | {r['median_s']:.3f} "
                 f"({r['min_s']:.3f}-{r['max_s']:.3f}) | {r['throughput_qps']:.0f} | **{r['efficiency']:.3f}** | "
                 f"{r['round_trips']} | {r['wire_bytes']} | {r['model_s']:.3f} ({100 * r['residual']:+.1f} %) | "
                 f"{ho} | {r['identical']} |")
    at200 = [r for r in rows if r["rtt_us"] == VALIDATE_RTT]
    L += ["", "Efficiency at 200 us: " + ", ".join(f"{r['label']} {r['efficiency']:.3f}" for r in at200) +
          f" (target: at least 0.8 with default batching: "
          f"{'met' if all(r['efficiency'] >= 0.8 for r in at200 if r['batching'] == 'default') else 'NOT met'}, "
          f"at the {statistics.median(r['achieved_rtt_us'] for r in at200):.0f} us the probes measured). "
          "The model at exactly 200 us: " + ", ".join(
              f"{p['workers']} worker{'s' if p['workers'] > 1 else ''} {p['efficiency']:.3f}" for p in preds
              if p["engine"] == "batched" and p["rtt_us"] == VALIDATE_RTT) + ".",
          ""]
    L += frames_note(rows)
    L += level_diagnosis(rows)
    L += ["", "## Model", "",
          "Per pyramid level l:", "",
          "    T_l = s*Q_l + c*P_l/N + R_l*(RTT + t_rt) + b*B_l", "",
          "Q_l queries, P_l comparisons, R_l round trips (one per engine batch: a wavefront step), B_l wire "
          "bytes, all from the level's report; N workers; the RTT's coefficient is 1 (a round trip waits one "
          "RTT); a run's time is the sum over its levels. b comes from the coordinator's CPU time (read from "
          "/proc per run): cpu = a + b*B by least squares over the default-batching runs, B varying with the "
          "worker count; wall time cannot tell a byte's cost from the 2-worker runs' sharing of 2 cores. "
          "s, c and t_rt: weighted least squares (residuals over sqrt(T_l)) over every measured level of "
          "every configuration and RTT.", "",
          "| parameter | fitted on all points | fitted without 200 us |", "|---|---|---|"]
    names = {"s": ("s: coordinator, per query", 1e6, "us"), "c": ("c: worker, per comparison", 1e9, "ns"),
             "t_rt": ("t_rt: per round trip, fixed", 1e6, "us"), "b": ("b: per wire byte (CPU fit)", 1e9, "ns")}
    for k in [*TERMS, "b"]:
        name, f, unit = names[k]
        L.append(f"| {name} | {full[k] * f:.4g} {unit} | " + (f"{held[k] * f:.4g} {unit}" if held else "-") + " |")
    if full["clamped"]:
        L += ["", f"Fitted negative and set to 0 (the points cannot support them): {', '.join(full['clamped'])}."]
    cpu_c = statistics.median(r["worker_cpu_per_comparison_ns"] for r in rows)
    relay = [r["cpu_relay_median_s"] / r["median_s"] for r in rows if r["cpu_relay_median_s"]]
    L += ["", f"1/b = {1 / full['b'] / 1e6 if full['b'] > 0 else float('inf'):.0f} MB/s: the rate at which the "
          "coordinator's CPU handles wire bytes (framing, syscalls, merging answers), not the veth's capacity. "
          f"The coordinator's CPU time outside the bytes: {full['coordinator_cpu_intercept']:.3f} s per run.",
          f"Check on c: the workers' own CPU time per comparison is {cpu_c:.3g} ns (median over "
          f"configurations), against the fitted {full['c'] * 1e9:.3g} ns of wall time."]
    if relay:
        L.append(f"The relay's CPU time: {100 * max(relay):.1f} % of a run's time at most.")
    if held:
        errs = [abs(r["heldout_error"]) for r in rows if r["rtt_us"] == VALIDATE_RTT]
        L.append(f"Validation: fitted without the {VALIDATE_RTT} us points, the model predicts them within "
                 f"{100 * max(errs):.1f} % (mean {100 * statistics.mean(errs):.1f} %); residuals of the full fit: "
                 f"at most {100 * max(abs(r['residual']) for r in rows):.1f} %.")
    L += ["", "### Predictions (one core per worker and one for the coordinator, assumed)", "",
          "From the 1-worker default-batching levels: comparisons as measured, wire bytes times N (every worker "
          "gets every query), the fitted parameters. `unbatched`: the same job with one round trip per query "
          "(an engine without wavefront batches), to show what batching buys.", "",
          "| workers | engine | RTT (us) | s | queries/s | efficiency vs 0 us | speed-up vs 1 worker | "
          "serial / compute / RTT / per round trip / bytes (s) |", "|---|---|---|---|---|---|---|---|"]
    for p in preds:
        t = p["terms_s"]
        L.append(f"| {p['workers']} | {p['engine']} | {p['rtt_us']} | {p['seconds']:.3f} | "
                 f"{p['throughput_qps']:.0f} | {p['efficiency']:.3f} | {p['speedup_vs_1']:.2f} | "
                 f"{t['serial']:.3f} / {t['compute']:.3f} / {t['rtt']:.3f} / {t['per_round_trip']:.3f} / "
                 f"{t['bytes']:.3f} |")
    L += ["", "### What dominates, and where the model breaks", ""]
    L += dominance(full, rows, preds)
    L += ["", f"Embedded reference run: {raw['embedded_s']:.3f} s engine time, 2 threads.",
          "Plot: `netem.png` (script `netem.gp`); data: `netem.json`."]
    return "\n".join(L) + "\n"


def frames_note(rows):
    """What the small-frame setting changes, from the rows themselves."""
    pick = lambda b: next(r for r in rows if r["batching"] == b and r["workers"] == max(WORKERS) and r["rtt_us"] == 0)
    d, sm = pick("default"), pick("small")
    if d["round_trips"] != sm["round_trips"]:
        return []
    return [f"Small frames do not add round trips ({d['round_trips']} in both settings): the coordinator queues "
            "all of a step's frames before it reads the answers (pipelining), so `--pipeline-queries` sets how a "
            "round trip's queries are cut into frames, not how many round trips there are. They cost frames "
            f"instead: {sm['wire_bytes'] / d['wire_bytes']:.2f}x the wire bytes, "
            f"{statistics.median(sm['cpu_coordinator_s']) / statistics.median(d['cpu_coordinator_s']):.2f}x the "
            "coordinator's CPU time and "
            f"{sm['cpu_relay_median_s'] / max(d['cpu_relay_median_s'], 1e-9):.1f}x the relay's at 0 us. What "
            "keeps the efficiency is the engine's batch: one round trip per wavefront step, its queries all in "
            "it; the `unbatched` lines of the predictions (one round trip per query) show what it would be "
            "without.", ""]


def level_diagnosis(rows):
    """Where the added RTT's time goes, per level: the 2-worker default
    configuration at 0 us and at the validation RTT. A level whose
    batches are small (few queries per round trip) loses most."""
    pick = lambda rtt: next((r for r in rows if r["workers"] == max(WORKERS) and r["batching"] == "default"
                             and r["rtt_us"] == rtt), None)
    base, slow = pick(0), pick(VALIDATE_RTT)
    if base is None or slow is None:
        return []
    L = [f"Per level, {base['label']}, 0 us against {VALIDATE_RTT} us (achieved {slow['achieved_rtt_us']:.0f} us): "
         "the time the RTT added per round trip, against the RTT itself, says whether the round trips are "
         "what costs (queries per round trip: the engine's mean batch).", "",
         "| level | queries | round trips | queries per round trip | s at 0 us | s at 200 us | added s | "
         "added per round trip (us) | efficiency |", "|---|---|---|---|---|---|---|---|---|"]
    for a, b in zip(base["levels"], slow["levels"]):
        added = b["T"] - a["T"]
        L.append(f"| {a['level']} | {a['Q']} | {a['R']} | {a['Q'] / max(a['R'], 1):.0f} | {a['T']:.3f} | "
                 f"{b['T']:.3f} | {added:+.3f} | {1e6 * added / max(a['R'], 1):.0f} | "
                 f"{a['T'] / b['T'] if b['T'] > 0 else 0:.3f} |")
    return L


def dominance(p, rows, preds):
    one = lambda n, eng, rtt: next(x for x in preds if x["workers"] == n and x["engine"] == eng and x["rtt_us"] == rtt)
    out = []
    rtts = sorted({x["rtt_us"] for x in preds})
    for n in [2, *PREDICT_N]:
        for rtt in (rtts[0], rtts[len(rtts) // 2], rtts[-1]):
            t = one(n, "batched", rtt)["terms_s"]
            total = sum(t.values())
            big = max(t, key=t.get)
            out.append(f"* {n} workers at {rtt} us: {big} is {100 * t[big] / total:.0f} % of the predicted time "
                       f"({', '.join(f'{k} {100 * v / total:.0f} %' for k, v in t.items())}).")
    out += ["* Assumptions that break here: the measured points come from 2 cores that the coordinator, the "
            "workers, the relay and the client share, so c (per comparison) absorbs the contention of the "
            "coordinator's own work with the workers', and 1 and 2 workers are the only worker counts the fit "
            "sees: the 1/N and N shapes of the compute and byte terms are extrapolated to 16 and 64, where a "
            "worker's slice of the reference is 16-64 times smaller (cache effects, fixed per-scan costs and the "
            "coordinator's merge of N answers per query are not in the model beyond the bytes term). "
            "Bandwidth is taken as unlimited beyond b (no link saturation); a real switch adds queueing."]
    return out


def measure(a, build, out):
    """Runs the series; returns and saves (netem-runs.json) everything
    measured, for analyse() or a later --analyse."""
    topo, procs = Topology(), Procs()

    def cleanup():
        procs.close()
        topo.close()

    atexit.register(cleanup)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit("netem: terminated"))
    info = machine()
    info["load_start"] = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as td:
        tmp = Path(td)
        try:
            topo.create()
            method, why, verified, configs, runs, emb_report = run_series(a, build, tmp, topo, procs)
        except RuntimeError as e:
            sys.exit(f"netem: {e}")
        finally:
            cleanup()
    info["load_end"] = os.getloadavg()[0]
    raw = {"machine": info, "method": method, "why": why, "quick": a.quick, "reps": a.reps, "rtts": a.rtts,
           "embedded_s": emb_report["seconds"], "verified_rtt": {str(k): v for k, v in verified.items()},
           "configs": [[c.n, c.batching] for c in configs],
           "runs": {f"{k} {rtt}": v for (k, rtt), v in runs.items()}}
    (out / "netem-runs.json").write_text(json.dumps(raw, indent=1))
    return raw


def analyse(raw, out):
    rtts = raw["rtts"]
    verified = {int(k): v for k, v in raw["verified_rtt"].items()}
    configs = [Config(n, b) for n, b in raw["configs"]]
    runs = {(c.key, rtt): raw["runs"][f"{c.key} {rtt}"] for c in configs for rtt in rtts}
    rows = summarise(configs, runs, rtts, verified)
    full, held = model(rows, rtts)
    preds = predictions(full, rows, rtts)
    curves = {(n, eng): curve(full, rows, n, eng == "unbatched") for n in [1, 2, *PREDICT_N]
              for eng in ("batched", "unbatched")}
    (out / "netem.json").write_text(json.dumps(
        {"machine": raw["machine"], "method": raw["method"], "why": raw["why"],
         "job": "512x512" if raw["quick"] else "1024x1024", "reps": raw["reps"], "verified_rtt": verified,
         "rows": rows, "model": full, "model_without_200us": held, "predictions": preds}, indent=1))
    md = markdown(raw, verified, rows, full, held, preds)
    (out / "netem.md").write_text(md)
    plot(out, rows, curves, rtts)
    print(md)
    if not all(r["identical"] for r in rows):
        sys.exit("netem: an output differs from the embedded run's")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--build", default="build")
    ap.add_argument("--out", default="bench/results")
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="a 512x512 output instead of 1024x1024")
    ap.add_argument("--rtts", default=",".join(map(str, RTTS_US)), help="RTTs in us, the first the baseline")
    ap.add_argument("--method", choices=["auto", "relay"], default="auto",
                    help="relay: the user-space relay even where netem exists")
    ap.add_argument("--analyse", metavar="RUNS_JSON",
                    help="no measurement: the model, tables and plot again from a netem-runs.json")
    a = ap.parse_args()
    out = Path(a.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    if a.analyse:
        analyse(json.loads(Path(a.analyse).read_text()), out)
        return
    a.rtts = [int(x) for x in a.rtts.split(",")]
    if os.geteuid() != 0:
        sys.exit("netem: needs root (network namespaces, tc, SCHED_FIFO)")
    if a.reps < 1 or not a.rtts or a.rtts[0] != 0:
        sys.exit("netem: --reps >= 1 and --rtts starting with 0 (the baseline)")
    build = Path(a.build).resolve()
    for exe in ("texsyn", "texsyn-server", "texsyn-worker", "bench/delay_relay"):
        if not (build / exe).exists():
            sys.exit(f"netem: {build / exe} is missing: run make first")
    analyse(measure(a, build, out), out)


if __name__ == "__main__":
    main()
