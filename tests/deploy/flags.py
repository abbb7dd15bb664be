"""The command lines of the systemd units and the Kubernetes manifests, run.

  flags.py ROOT BUILD_DIR TMP_DIR

systemd-analyze and the schema check say nothing of whether the programs
accept the options the files give them. This runs each file's coordinator and
worker command as written, with only what the deployment supplies replaced:
the programs' directory (/usr/local/bin -> BUILD_DIR), the addresses (a free
loopback port for the coordinator's, 127.0.0.1:0 for a Modbus plane), the
directories (spool, credentials) and the names systemd and Kubernetes fill in
(%H, %i; $(POD_NAME)). The worker must join the coordinator, be calibrated
with the threads the file gives it, and be named as the file names it.
Prints PASS/FAIL lines; exits 1 on any failure.
"""
import os
import re
import shlex
import shutil
import socket
import subprocess
import sys
import time

import yaml

WAIT = 30  # seconds for the worker to be ready


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def unit_exec(path, env, specifiers):
    """A unit's ExecStart= as argv, as systemd expands it: ${V} is one word,
    a lone $V splits into zero or more, %X from specifiers. The unit's own
    Environment= lines come first, env overrides them."""
    full = {}
    exec_line = None
    with open(path, encoding="utf-8") as f:
        for line in f:
            key, _, value = line.strip().partition("=")
            if key == "Environment":
                name, _, val = value.partition("=")
                full[name] = val
            elif key == "ExecStart":
                exec_line = value
    if exec_line is None:
        raise ValueError(f"{path}: no ExecStart=")
    full.update(env)

    def spec(m):
        if m.group(1) not in specifiers:
            raise ValueError(f"{path}: specifier %{m.group(1)} not supplied by the test")
        return specifiers[m.group(1)]

    def var(m):
        if m.group(1) not in full:
            raise ValueError(f"{path}: ${{{m.group(1)}}} not supplied by the test")
        return full[m.group(1)]

    argv = []
    for word in shlex.split(exec_line):
        lone = re.fullmatch(r"\$([A-Za-z_][A-Za-z0-9_]*)", word)
        if lone:
            argv += full.get(lone.group(1), "").split()
            continue
        word = re.sub(r"%([A-Za-z])", spec, word)
        argv.append(re.sub(r"\$\{([A-Za-z_][A-Za-z0-9_]*)\}", var, word))
    return argv


def k8s_container(path, name):
    """command + args of container `name` in the manifests of path."""
    with open(path, encoding="utf-8") as f:
        for doc in yaml.safe_load_all(f):
            if not doc or doc.get("kind") != "Deployment":
                continue
            for c in doc["spec"]["template"]["spec"]["containers"]:
                if c["name"] == name:
                    return c.get("command", []) + c.get("args", [])
    raise ValueError(f"{path}: no container {name}")


def replace_all(argv, pairs):
    out = []
    for a in argv:
        for old, new in pairs:
            a = a.replace(old, new)
        out.append(a)
    return out


def wait_ready(build, addr, secret, server, worker, threads):
    """The worker's line in `texsyn workers`, once it is ready."""
    env = dict(os.environ, TEXSYN_SERVER=addr, TEXSYN_SECRET_FILE=secret)
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        if server.poll() is not None:
            return f"the coordinator exited ({server.returncode})"
        if worker.poll() is not None:
            return f"the worker exited ({worker.returncode})"
        r = subprocess.run([f"{build}/texsyn", "workers"], env=env, capture_output=True, text=True)
        lines = [l for l in r.stdout.splitlines() if " active " in l]
        if lines:
            cols = lines[0].split()
            if len(lines) != 1 or cols[2] != threads:
                return f"expected one ready worker of {threads} threads, got: {lines}"
            return None
        time.sleep(0.2)
    return f"no worker ready after {WAIT} s"


def run_pair(label, build, tmp, server_argv, worker_argv, addr, secret, name, threads):
    d = os.path.join(tmp, label)
    os.makedirs(d, exist_ok=True)
    procs = []
    try:
        with open(f"{d}/server.log", "w") as log:
            procs.append(subprocess.Popen(server_argv, stdout=log, stderr=subprocess.STDOUT, cwd=d))
        with open(f"{d}/worker.log", "w") as log:
            procs.append(subprocess.Popen(worker_argv, stdout=log, stderr=subprocess.STDOUT, cwd=d))
        problem = wait_ready(build, addr, secret, procs[0], procs[1], threads)
        if problem is None:
            with open(f"{d}/server.log") as f:
                log_text = f.read()
            if f" {name})" not in log_text:
                problem = f"no worker named {name!r} in the coordinator's log"
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()
    if problem:
        print(f"  {label}: {problem}")
        print("  server: " + " ".join(server_argv))
        print("  worker: " + " ".join(worker_argv))
        for f in ("server.log", "worker.log"):
            with open(f"{d}/{f}") as fh:
                print(f"  --- {f}\n" + fh.read())
    print(f"{'FAIL' if problem else 'ok  '} {label}: coordinator and worker {name} from the file's command lines")
    return problem is None


def checked(label, run):
    """run() -> bool; a file the test cannot make sense of is a failure too."""
    try:
        return run()
    except (OSError, ValueError, KeyError, TypeError, yaml.YAMLError) as e:
        print(f"FAIL {label}: {e}")
        return False


def main(argv):
    if len(argv) != 4:
        print("usage: flags.py ROOT BUILD_DIR TMP_DIR", file=sys.stderr)
        return 2
    root, build, tmp = argv[1:]
    os.makedirs(tmp, exist_ok=True)
    cred = os.path.join(tmp, "credentials")
    os.makedirs(cred, exist_ok=True)
    secret = os.path.join(cred, "secret")
    fd = os.open(secret, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    os.write(fd, os.urandom(16).hex().encode())
    os.close(fd)
    host = socket.gethostname()
    ok = True

    # systemd: the environment files' variables and what systemd sets.
    port = free_port()
    addr = f"127.0.0.1:{port}"
    units = os.path.join(root, "deploy", "systemd")
    # The units' credentials: the coordinator's keys directory as systemd
    # copies it (keys_NAME.key), the worker's worker.key; `texsyn workers`
    # uses the admin key.
    sd_cred = os.path.join(tmp, "systemd-credentials")
    os.makedirs(sd_cred, exist_ok=True)
    for kind, file in (("admin:ops", "keys_admin.key"), ("worker:pool", "keys_worker.key")):
        path = os.path.join(sd_cred, file)
        if os.path.exists(path):
            os.unlink(path)
        subprocess.run([f"{build}/texsyn-server", "--gen-secret", kind, path], check=True, capture_output=True)
    shutil.copy(os.path.join(sd_cred, "keys_worker.key"), os.path.join(sd_cred, "worker.key"))
    sd_env = {"CREDENTIALS_DIRECTORY": sd_cred, "STATE_DIRECTORY": os.path.join(tmp, "systemd-state"),
              "TEXSYN_LISTEN": addr, "TEXSYN_COORDINATOR": addr, "TEXSYN_WORKER_OPTS": "--threads 1"}
    bins = [("/usr/local/bin/", build + "/")]
    def systemd():
        server = replace_all(unit_exec(f"{units}/texsyn-server.service", sd_env, {"H": host}), bins)
        worker = replace_all(unit_exec(f"{units}/texsyn-worker@.service", sd_env, {"H": host, "i": "1"}), bins)
        return run_pair("systemd", build, tmp, server, worker, addr, os.path.join(sd_cred, "keys_admin.key"),
                        f"{host}-1", "1")
    ok &= checked("systemd", systemd)

    # Kubernetes: the Service's name and the pod's paths.
    port = free_port()
    addr = f"127.0.0.1:{port}"
    k8s = os.path.join(root, "deploy", "k8s")
    paths = bins + [("/run/texsyn/secret", secret), ("/var/lib/texsyn", os.path.join(tmp, "k8s-spool"))]
    def kubernetes():
        server = replace_all(k8s_container(f"{k8s}/server.yaml", "texsyn-server"),
                             paths + [("0.0.0.0:7070", addr)])
        worker = replace_all(k8s_container(f"{k8s}/worker.yaml", "texsyn-worker"),
                             paths + [("texsyn-server:7070", addr), ("0.0.0.0:1502", "127.0.0.1:0"),
                                      ("$(POD_NAME)", "texsyn-worker-0")])
        # As many threads as the file gives it, else the online CPUs.
        threads = [a.split("=", 1)[1] for a in worker if a.startswith("--threads=")]
        return run_pair("k8s", build, tmp, server, worker, addr, secret, "texsyn-worker-0",
                        threads[0] if threads else str(os.cpu_count()))
    ok &= checked("k8s", kubernetes)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main(sys.argv))
