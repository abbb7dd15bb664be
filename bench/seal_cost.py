#!/usr/bin/python3
"""What sealing every frame costs (issue 29): the seed's Table 3.3 job
(brick.png 512^2 -> 1024^2, L=5, W_N=7, W_B=3, parity, --refine 0, exact)
on a coordinator with 3 one-thread workers (--join), all with the same
--secret-file, built twice: --base (a build without sealed frames, e.g.
the commit this one started from) and --build (sealed). Both pools are up
at once and the runs alternate strictly (base, sealed, base, ...), so drift
in the machine's speed falls on both. Every output is compared byte for
byte with the first base run's. Prints the medians, the ratio
sealed / base and the spread; writes --json if given.
Usage: bench/seal_cost.py --base BUILD --build BUILD [--reps 5] [--json F]
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from cluster import start, stop  # noqa: E402
from scaling import table33_args  # noqa: E402

WORKERS = 3


class SecretPool:
    """A coordinator and WORKERS one-thread workers of one build, all with
    the secret."""

    def __init__(self, build, tmp, tag, secret):
        self.build, self.secret, self.procs = build, secret, []
        sec = ["--secret-file", secret]
        self.server, self.addr = start([build / "texsyn-server", "--listen", "127.0.0.1:0", "--spool",
                                        tmp / f"spool-{tag}", *sec], tmp / f"server-{tag}.log")
        for i in range(WORKERS):
            self.procs.append(subprocess.Popen(
                [str(build / "texsyn-worker"), "--join", self.addr, "--threads", "1", "--name", f"{tag}-{i}", *sec],
                stdout=subprocess.DEVNULL, stderr=open(tmp / f"worker-{tag}-{i}.log", "w")))
        for _ in range(1200):
            out = self.cli(["workers", "--server", self.addr]).stdout
            if out.count(" active ") >= WORKERS:
                return
            time.sleep(0.05)
        sys.exit(f"bench: the {tag} workers did not become ready")

    def cli(self, args):
        env = dict(os.environ, TEXSYN_SECRET_FILE=str(self.secret))
        return subprocess.run([str(self.build / "texsyn"), *map(str, args)], capture_output=True, text=True, env=env)

    def run(self, out):
        """The job's wall time and the bytes its frames took on the worker
        links (the report's wire_bytes, before sealing)."""
        rep = out.with_suffix(".json")
        t0 = time.monotonic()
        p = self.cli([*table33_args(), "-o", out, "--report", rep, "--quiet", "--server", self.addr])
        wall = time.monotonic() - t0
        if p.returncode != 0:
            sys.exit(f"bench: the job failed on {self.build}:\n{p.stderr}")
        return wall, sum(lv.get("wire_bytes", 0) for lv in json.loads(rep.read_text()).get("levels", []))

    def down(self):
        stop([*self.procs, self.server])


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", type=Path, required=True)
    ap.add_argument("--build", type=Path, required=True)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--json", type=Path)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="seal-cost-") as t:
        tmp = Path(t)
        secret = tmp / "secret"
        secret.write_bytes(os.urandom(32).hex().encode() + b"\n")
        secret.chmod(0o600)
        pools = {"base": SecretPool(a.base.resolve(), tmp, "base", secret),
                 "sealed": SecretPool(a.build.resolve(), tmp, "sealed", secret)}
        walls, wire, want = {"base": [], "sealed": []}, 0, None
        try:
            for r in range(a.reps):
                for name, pool in pools.items():
                    out = tmp / f"{name}-{r}.png"
                    wall, wire = pool.run(out)
                    walls[name].append(wall)
                    data = out.read_bytes()
                    want = want or data
                    if data != want:
                        sys.exit(f"bench: run {r} on {name} gave other bytes than the first base run")
                    print(f"run {r} {name}: {walls[name][-1]:.2f} s", flush=True)
        finally:
            for p in pools.values():
                p.down()
    med = {k: statistics.median(v) for k, v in walls.items()}
    res = {"reps": a.reps, "workers": WORKERS, "walls": walls, "median": med,
           "ratio": med["sealed"] / med["base"], "identical_bytes": True, "wire_bytes": wire}
    print(f"median base {med['base']:.2f} s (spread {min(walls['base']):.2f}-{max(walls['base']):.2f}), sealed "
          f"{med['sealed']:.2f} s (spread {min(walls['sealed']):.2f}-{max(walls['sealed']):.2f}): ratio "
          f"{res['ratio']:.3f}; outputs identical; {wire / 1e6:.1f} MB on the worker links per job")
    if a.json:
        a.json.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
