#!/usr/bin/python3
"""How fast the coordinator answers its clients while it works: a status
request ('W', every job) and a pool request ('P', what `texsyn workers`
shows), 20 each on a fresh connection (identify included), sent by a minimal
client speaking the protocol, while a job runs on 3 workers and on the idle
coordinator. Then the whole `texsyn status` process, 20 runs, which adds the
program's start to the answer. With --before BUILD, the `texsyn` of another
build (e.g. the code before a change) is timed too, its runs alternating
with this build's so both see the same load. Medians and maxima, and the
CPU they ran on. Writes latency.json and latency.md into --out.
"""
import argparse
import json
import os
import socket
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cluster import start, stop, wait_ready  # noqa: E402
from wire import DATA, REPO  # noqa: E402

JOB = ["--ref", DATA / "textures/brick.png", "--size", "1024x1024", "--levels", 5, "--wn", 7, "--wb", 3]
CALLS = 20
PROTO_VERSION = 8


def frame(kind, payload, fid=1):
    return b"TS" + bytes([PROTO_VERSION]) + kind.encode() + struct.pack("<II", len(payload), fid) + payload


def read_frame(sock):
    head = b""
    while len(head) < 12:
        head += sock.recv(12 - len(head))
    length = struct.unpack_from("<I", head, 4)[0]
    body = b""
    while len(body) < length:
        body += sock.recv(length - len(body))
    return chr(head[3]), body


def request(addr, kind, payload):
    """Seconds from connecting to the answer of one request."""
    host, port = addr.rsplit(":", 1)
    t = time.perf_counter()
    with socket.create_connection((host, int(port))) as s:
        s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        name = b"bench/latency"
        s.sendall(frame("I", struct.pack("<BIHB", 3, 0, 0, 0) + struct.pack("<H", len(name)) + name, 0))
        if read_frame(s)[0] != "I":
            sys.exit("bench: the coordinator did not identify")
        s.sendall(frame(kind, payload))
        got = read_frame(s)[0]
    if got != kind:
        sys.exit(f"bench: expected a '{kind}' answer, got '{got}'")
    return time.perf_counter() - t


def timed(build, *args):
    t = time.perf_counter()
    subprocess.run([str(build / "texsyn"), *map(str, args)], check=True, capture_output=True)
    return time.perf_counter() - t


def series(build, before, addr):
    s = {"status request": [request(addr, "W", struct.pack("<QB", 0, 0)) for _ in range(CALLS)],
         "pool request": [request(addr, "P", b"") for _ in range(CALLS)],
         "texsyn status (process)": []}
    if before:
        s["texsyn status (process, before)"] = []
    for _ in range(CALLS):
        s["texsyn status (process)"].append(timed(build, "status", "--server", addr))
        if before:
            s["texsyn status (process, before)"].append(timed(before, "status", "--server", addr))
    return s


def cpu_model():
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown"


def job_state(build, addr, job_id):
    out = subprocess.run([str(build / "texsyn"), "status", str(job_id), "--server", addr], capture_output=True,
                         text=True).stdout
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--build", default=str(REPO / "build"))
    ap.add_argument("--before", help="another build whose `texsyn status` is timed alongside")
    ap.add_argument("--before-label", default="another build", help="what --before is, for latency.md")
    ap.add_argument("--out", default=str(REPO / "bench" / "results"))
    ap.add_argument("--quick", action="store_true", help="accepted for bench/run.sh")
    args = ap.parse_args()
    build, out = Path(args.build), Path(args.out)
    before = Path(args.before) if args.before else None
    with tempfile.TemporaryDirectory() as t:
        tmp = Path(t)
        procs, addrs = [], []
        for i in range(3):
            p, a = start([build / "texsyn-worker", "--listen", "127.0.0.1:0", "--threads", 1], tmp / f"w{i}.log")
            procs.append(p)
            addrs.append(a)
        server, addr = start([build / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp / "spool",
                              "--workers", ",".join(addrs)], tmp / "server.log")
        procs.append(server)
        try:
            wait_ready(build, addr, 3)
            idle = series(build, before, addr)
            sub = subprocess.run([str(build / "texsyn"), "synth", *map(str, JOB), "-o", str(tmp / "o.png"),
                                  "--quiet", "--detach", "--server", addr], check=True, capture_output=True, text=True)
            job_id = int(sub.stdout.strip())
            while "running" not in job_state(build, addr, job_id):
                time.sleep(0.05)
            busy = series(build, before, addr)
            still = "running" in job_state(build, addr, job_id)
        finally:
            stop(procs)
    rows = {}
    for label, s in (("idle", idle), ("job on 3 workers", busy)):
        for call, v in s.items():
            rows[f"{call}, {label}"] = {"median_ms": 1000 * statistics.median(v), "max_ms": 1000 * max(v),
                                        "all_ms": [round(1000 * x, 2) for x in v]}
    rows["job still running after the calls"] = still
    rows["cpu"] = f"{cpu_model()}, {os.cpu_count()} cores"
    out.mkdir(parents=True, exist_ok=True)
    (out / "latency.json").write_text(json.dumps(rows, indent=1) + "\n")
    lines = ["| call | median | max |", "|---|---|---|"]
    for k, v in rows.items():
        if isinstance(v, dict):
            lines.append(f"| {k} | {v['median_ms']:.1f} ms | {v['max_ms']:.1f} ms |")
    lines.append(f"\nThe job was still running after the last call: {'yes' if still else 'no'}.")
    lines.append(f"CPU: {rows['cpu']}.")
    if before:
        lines.append(f"`before`: the `texsyn` of {args.before_label}, its runs alternating with this build's.")
    (out / "latency.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
