#!/usr/bin/python3
"""Fills the generated blocks of the command pages (doc/texsyn*.md) from the
built programs: between

    <!-- options: texsyn synth --help -->
    <!-- /options -->

a page holds what that command prints, whole, in a code block. The block is
copied, never parsed, so it follows whatever the help text becomes; `make doc`
runs this, and tests/integration/test_manual.py fails on a page whose block
differs from its program's output.

Usage: doc/gen.py [--build DIR] [--check] [PAGE.md ...]   (default: every page)
"""
import argparse
import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

DOC = Path(__file__).resolve().parent
PROGRAMS = ("texsyn", "texsyn-server", "texsyn-worker")
BLOCK = re.compile(r"(<!-- options: (?P<cmd>[^>]*?) -->\n)(?P<body>.*?)(<!-- /options -->)", re.S)
# What a help text says about the machine it ran on, made the same on every
# machine: the worker's default thread count names the online CPUs.
MACHINE = [(re.compile(r"online CPUs, \d+ here"), "online CPUs, N here")]


def pages():
    return sorted(DOC.glob("texsyn*.md"))


def help_text(cmd, build):
    """What `cmd` (texsyn ... --help) prints, run from the build directory."""
    argv = shlex.split(cmd)
    if argv[0] not in PROGRAMS:
        raise ValueError(f"options block names {argv[0]!r}: only {', '.join(PROGRAMS)} are documented")
    env = {k: v for k, v in os.environ.items() if not k.startswith("TEXSYN_")}
    env["LC_ALL"] = "C"
    p = subprocess.run([str(Path(build) / argv[0]), *argv[1:]], capture_output=True, text=True, env=env,
                       timeout=60)
    if p.returncode != 0:
        raise RuntimeError(f"`{cmd}` exited with status {p.returncode}:\n{p.stderr}")
    out = p.stdout or p.stderr
    for pattern, same in MACHINE:
        out = pattern.sub(same, out)
    return "\n".join(line.rstrip() for line in out.rstrip("\n").split("\n"))


def block_body(text):
    return f"```text\n{text}\n```\n"


def blocks(page_text):
    """(command, body as on the page) of every generated block."""
    return [(m.group("cmd"), m.group("body")) for m in BLOCK.finditer(page_text)]


def render(page_text, build):
    """The page with every block filled from the programs of `build`."""
    return BLOCK.sub(lambda m: m.group(1) + block_body(help_text(m.group("cmd"), build)) + m.group(4),
                     page_text)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--build", default=str(DOC.parent / "build"), help="where the programs are (build/)")
    ap.add_argument("--check", action="store_true", help="change nothing; exit 1 naming every stale page")
    ap.add_argument("pages", nargs="*", type=Path)
    args = ap.parse_args()
    stale = []
    for page in args.pages or pages():
        old = page.read_text()
        new = render(old, args.build)
        if new == old:
            continue
        stale.append(page)
        if not args.check:
            page.write_text(new)
            print(f"doc/gen.py: {page.name} updated")
    if args.check and stale:
        for page in stale:
            print(f"{page} is stale: run make doc", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
