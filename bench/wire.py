#!/usr/bin/python3
"""Bytes on the wire between the coordinator and its workers, counted by a
frame-aware proxy on every worker link (not by the coordinator's own
accounting), per frame type and direction.

Jobs: the seed's Table 3.3 job (brick 512^2 -> 1024^2, L=5, W_N=7, W_B=3,
parity) and an 11x11 colour window (aero1.jpg, --rgb-search --wn 11; a
320x240 and a 1280x960 output), each on 1 and 3 workers. Queries are the blocks searched, summed over the levels
of the job's report. Reported per job and pool size: coordinator egress per
query and worker (all frames, and query frames 'V' alone), query-image
loads and level changes 'R', slice loads 'N', and worker ingress per query
and worker; next to the egress measured before queries became positions
(bench/results/before-search-rebuild/wire.json), when present. Then a
re-slice: a fourth worker joins the Table 3.3 job in its finest level, and
the 'N' bytes the three first workers receive for it are counted. Writes
wire.json, wire-reslice.json and wire.md into --out.
"""
import argparse
import json
import os
import re
import socket
import struct
import subprocess
import sys
import tempfile
import threading
from collections import defaultdict
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "integration"))
from cluster import start, stop, wait_ready  # noqa: E402
from conftest import LoopbackProxy, shutdown_all  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TEXSYN_DATA", REPO.parent / "shared" / "data"))
JOBS = {
    "table33": ["--ref", DATA / "textures/brick.png", "--size", "1024x1024", "--levels", 5, "--wn", 7, "--wb", 3,
                "--parity"],
    "rgb-wn11": ["--ref", DATA / "aerial/aero1.jpg", "--size", "320x240", "--rgb-search", "--wn", 11, "--wb", 3],
    # The same window on an output 16 times as large: the reference travels
    # once per worker whatever the output, the queries with the output.
    "rgb-wn11-big": ["--ref", DATA / "aerial/aero1.jpg", "--size", "1280x960", "--rgb-search", "--wn", 11, "--wb",
                     3],
}
HEADER = 12


class CountingProxy(LoopbackProxy):
    """Forwards one worker link both ways and counts whole frames by type."""

    def __init__(self, target):
        self.count = {"out": defaultdict(int), "in": defaultdict(int)}
        self.lock = threading.Lock()
        super().__init__(target)

    def forward(self, a, b):
        for s in (a, b):
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        threading.Thread(target=self.pump, args=(a, b, "out"), daemon=True).start()
        threading.Thread(target=self.pump, args=(b, a, "in"), daemon=True).start()

    def pump(self, src, dst, way):
        buf = b""
        while True:
            try:
                data = src.recv(1 << 20)
            except OSError:
                data = b""
            if not data:
                shutdown_all(src, dst)
                return
            buf += data
            while len(buf) >= HEADER:
                length = struct.unpack_from("<I", buf, 4)[0]
                if len(buf) < HEADER + length:
                    break
                with self.lock:
                    self.count[way][chr(buf[3])] += HEADER + length
                buf = buf[HEADER + length:]
            try:
                dst.sendall(data)
            except OSError:
                return


def run_job(build, tmp, name, nworkers):
    procs, proxies = [], []
    for i in range(nworkers):
        p, a = start([build / "texsyn-worker", "--listen", "127.0.0.1:0", "--threads", 1], tmp / f"w{i}.log")
        procs.append(p)
        proxies.append(CountingProxy(a))
    server, addr = start([build / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp / f"spool-{name}-{nworkers}",
                          "--heartbeat", 0, "--modbus-poll", 0, "--workers", ",".join(x.addr for x in proxies)],
                         tmp / "server.log")
    procs.append(server)
    try:
        wait_ready(build, addr, nworkers)
        base = {id(x): {w: dict(x.count[w]) for w in x.count} for x in proxies}  # calibration and handshakes
        report = tmp / f"{name}-{nworkers}.json"
        subprocess.run([str(build / "texsyn"), "synth", *map(str, JOBS[name]), "-o", str(tmp / f"{name}.png"),
                        "--quiet", "--report", str(report), "--server", addr], check=True)
        levels = json.loads(report.read_text())["levels"]
    finally:
        stop(procs)
    queries = sum(lv["blocks"] for lv in levels)
    out, inn = defaultdict(int), defaultdict(int)
    for x in proxies:
        for t, v in x.count["out"].items():
            out[t] += v - base[id(x)]["out"].get(t, 0)
        for t, v in x.count["in"].items():
            inn[t] += v - base[id(x)]["in"].get(t, 0)
    per = queries * nworkers
    return {"job": name, "workers": nworkers, "queries": queries,
            "egress_per_query_worker": sum(out.values()) / per, "egress_V_per_query_worker": out["V"] / per,
            "egress_N_bytes": out["N"], "ingress_per_query_worker": sum(inn.values()) / per,
            "egress_by_type": dict(out), "ingress_by_type": dict(inn)}


def run_reslice(build, tmp):
    """The Table 3.3 job on 3 workers; in its finest level a fourth joins
    and every set is cut again. What the three first workers receive in
    'N' frames for that re-slice, against what it would cost whole (the
    rows the coordinator logs as kept)."""
    procs, proxies = [], []
    for i in range(3):
        p, a = start([build / "texsyn-worker", "--listen", "127.0.0.1:0", "--threads", 1], tmp / f"r{i}.log")
        procs.append(p)
        proxies.append(CountingProxy(a))
    log = tmp / "reslice-server.log"
    server, addr = start([build / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp / "spool-reslice",
                          "--heartbeat", 0, "--modbus-poll", 0, "--workers", ",".join(x.addr for x in proxies)], log)
    procs.append(server)
    try:
        wait_ready(build, addr, 3)
        job = subprocess.Popen([str(build / "texsyn"), "synth", *map(str, JOBS["table33"]), "-o",
                                str(tmp / "reslice.png"), "--quiet", "--server", addr])
        levels = JOBS["table33"][JOBS["table33"].index("--levels") + 1]
        coarser = False  # a job that has not started its first level reads as the finest one
        while job.poll() is None:
            status = subprocess.run([str(build / "texsyn"), "status", "--server", addr], capture_output=True,
                                    text=True).stdout
            coarser = coarser or re.search(rf"level [1-{levels - 1}] of {levels}", status) is not None
            if coarser and f"level {levels} of {levels}" in status:
                break
        before = [x.count["out"].get("N", 0) for x in proxies]
        p, _ = start([build / "texsyn-worker", "--listen", "127.0.0.1:0", "--threads", 1, "--join", addr],
                     tmp / "r3.log")
        procs.append(p)
        if job.wait() != 0:
            raise SystemExit("the re-slice job failed")
    finally:
        stop(procs)
    sent_n = sum(x.count["out"].get("N", 0) - b for x, b in zip(proxies, before))
    lines = [ln for ln in log.read_text().splitlines() if "kept from their slices" in ln]
    if not lines:
        raise SystemExit("the fourth worker joined after the job's last batch: nothing was re-sliced")
    sent, kept = (int(v) for v in re.search(r"(\d+) bytes of rows sent, (\d+) kept", lines[-1]).groups())
    return {"job": "table33", "workers": "3 + 1 joining in level 0", "N_bytes_to_the_three": sent_n,
            "rows_sent_all_four": sent, "rows_kept": kept, "log": lines[-1]}


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--build", default=str(REPO / "build"))
    ap.add_argument("--out", default=str(REPO / "bench" / "results"))
    ap.add_argument("--quick", action="store_true", help="accepted for bench/run.sh; the figures are counts")
    args = ap.parse_args()
    build, out = Path(args.build), Path(args.out)
    rows = []
    with tempfile.TemporaryDirectory() as t:
        for name in JOBS:
            for n in (1, 3):
                rows.append(run_job(build, Path(t), name, n))
                r = rows[-1]
                print(f"{name:9s} {n} worker(s): {r['queries']} queries, egress {r['egress_per_query_worker']:.1f} "
                      f"B/query/worker (V {r['egress_V_per_query_worker']:.1f}), ingress "
                      f"{r['ingress_per_query_worker']:.1f}", flush=True)
    out.mkdir(parents=True, exist_ok=True)
    (out / "wire.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = ["| job | workers | queries | egress B/query/worker | of it 'V' | 'R' bytes | 'N' bytes | ingress B/query/worker | "
             "egress before (vectors) | ratio |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    before = {}
    old = out / "before-search-rebuild" / "wire.json"
    if old.exists():
        before = {(r["job"], r["workers"]): r["egress_per_query_worker"] for r in json.loads(old.read_text())}
    for r in rows:
        b = before.get((r["job"], r["workers"]))
        was = f"{b:.1f}" if b else "-"
        ratio = f"{b / r['egress_per_query_worker']:.1f}x" if b else "-"
        lines.append(f"| {r['job']} | {r['workers']} | {r['queries']} | {r['egress_per_query_worker']:.1f} | "
                     f"{r['egress_V_per_query_worker']:.1f} | {r['egress_by_type'].get('R', 0)} | {r['egress_N_bytes']} | "
                     f"{r['ingress_per_query_worker']:.1f} | {was} | {ratio} |")
    with tempfile.TemporaryDirectory() as t:
        rs = run_reslice(build, Path(t))
    print(f"re-slice: {rs['N_bytes_to_the_three']} bytes of N to the three workers; rows sent {rs['rows_sent_all_four']}, "
          f"kept {rs['rows_kept']}", flush=True)
    (out / "wire-reslice.json").write_text(json.dumps(rs, indent=1) + "\n")
    whole = rs["rows_sent_all_four"] + rs["rows_kept"]
    lines += ["", "Re-slice in level 0 (Table 3.3 job, 3 workers, a fourth joins): 'N' bytes to the three: "
              f"{rs['N_bytes_to_the_three']}; rows sent to all four: {rs['rows_sent_all_four']} of {whole} "
              f"({100 * rs['rows_sent_all_four'] / whole:.0f} %), the rest kept by the workers."]
    (out / "wire.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
