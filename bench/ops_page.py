#!/usr/bin/python3
"""The operations page (texsyn-server --http) while a job runs on 2 workers:
a headless-chromium screenshot of `/` (ops-page.png), and how long the
coordinator takes to answer `/`, `/status.json` and `/metrics` (20 requests
each, median and maximum), next to the same requests on the idle
coordinator, and what the first thumbnail of a 1024x1024 result costs
against a cached one. Writes ops-page.png, ops_page.json and ops_page.md
into --out.
"""
import argparse
import json
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cluster import start, stop, wait_ready  # noqa: E402
from wire import DATA, REPO  # noqa: E402

JOB = ["--ref", DATA / "textures/brick.png", "--size", "1024x1024", "--levels", 5, "--wn", 7, "--wb", 3]
CALLS = 20
PAGES = ("/", "/status.json", "/metrics")


def fetch(url):
    """Seconds to the last byte, and the body."""
    t = time.perf_counter()
    with urllib.request.urlopen(url, timeout=60) as r:
        body = r.read()
    return time.perf_counter() - t, body


def series(base):
    rows = {}
    for page in PAGES:
        times = [fetch(base + page)[0] for _ in range(CALLS)]
        rows[page] = {"median_ms": statistics.median(times) * 1e3, "max_ms": max(times) * 1e3}
    return rows


def job_state(base, job):
    st = json.loads(fetch(base + "/status.json")[1])
    return next(j for j in st["jobs"] if j["id"] == job)


def screenshot(url, path):
    exe = shutil.which("chromium")
    if exe is None:
        sys.exit("bench: chromium is not installed (deploy/install-deps.sh installs it)")
    with tempfile.TemporaryDirectory() as profile:
        subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                        "--disable-background-networking", "--disable-component-update", "--disable-sync",
                        f"--user-data-dir={profile}", "--hide-scrollbars", "--window-size=1100,620",
                        f"--screenshot={path}", url], check=True, capture_output=True, timeout=120)


def cpu_model():
    for line in Path("/proc/cpuinfo").read_text().splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return "unknown"


def main():
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--build", default=str(REPO / "build"))
    ap.add_argument("--out", default=str(REPO / "bench" / "results"))
    ap.add_argument("--quick", action="store_true", help="accepted for bench/run.sh")
    a = ap.parse_args()
    build, out = Path(a.build).resolve(), Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="texsyn-ops-"))
    procs = []
    try:
        addrs = []
        for i in range(2):
            p, addr = start([build / "texsyn-worker", "--listen", "127.0.0.1:0", "--threads", 1, "--name", f"w{i}"],
                            tmp / f"w{i}.log")
            procs.append(p)
            addrs.append(addr)
        p, addr = start([build / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp / "spool", "--workers",
                         ",".join(addrs), "--http", "127.0.0.1:0"], tmp / "server.log")
        procs.insert(0, p)
        base = "http://" + re.search(r"\(http (\S+)\)", p.banner).group(1)
        wait_ready(build, addr, 2)
        idle = series(base)
        sub = subprocess.run([str(x) for x in [build / "texsyn", "synth", "--server", addr, *JOB, "-o",
                                               tmp / "out.png", "--detach"]], capture_output=True, text=True,
                             check=True)
        job = int(sub.stdout.split()[-1])
        while job_state(base, job)["permille"] < 100:
            time.sleep(0.2)
        busy = series(base)
        screenshot(base + "/", out / "ops-page.png")
        while job_state(base, job)["state"] not in ("done", "failed", "canceled"):
            time.sleep(0.5)
        first = fetch(f"{base}/jobs/{job}/thumb.png")[0]
        cached = statistics.median(fetch(f"{base}/jobs/{job}/thumb.png")[0] for _ in range(CALLS))
    finally:
        stop(procs)
        shutil.rmtree(tmp, ignore_errors=True)
    result = {"cpu": cpu_model(), "idle": idle, "running": busy,
              "thumb_first_ms": first * 1e3, "thumb_cached_median_ms": cached * 1e3}
    (out / "ops_page.json").write_text(json.dumps(result, indent=1) + "\n")
    lines = [f"# Operations page answer times ({result['cpu']})", "",
             "| page | idle median ms | idle max ms | job running median ms | job running max ms |",
             "|---|---|---|---|---|"]
    for page in PAGES:
        i, b = idle[page], busy[page]
        lines.append(f"| `{page}` | {i['median_ms']:.2f} | {i['max_ms']:.2f} | {b['median_ms']:.2f} | "
                     f"{b['max_ms']:.2f} |")
    lines += ["", f"Thumbnail of the 1024x1024 result: first request {first * 1e3:.0f} ms (decode, scale, "
              f"write), cached {cached * 1e3:.2f} ms (median of {CALLS})."]
    (out / "ops_page.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
