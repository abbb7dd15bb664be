"""The command line a newcomer meets (issue 26): the README's quick start
run as written in a clean shell, the closing line saying where a job ran,
output formats refused before any work, Ctrl-C of a cluster run, fetch of
outputs a job never made, hints that name the real cause, progress
without a terminal, --version, "did you mean", the generated --help."""
import json
import os
import re
import signal
import socket
import subprocess

from conftest import BUILD, REPO, jobs_listed, run

SCRIPT = REPO / "deploy" / "local-cluster.sh"


def clean_shell(script, cwd, timeout=300):
    """bash -c script with nothing in the environment but a PATH that finds
    the binaries under test (as after `make install`), run in cwd."""
    env = {"PATH": f"{BUILD}:/usr/bin:/bin", "HOME": str(cwd)}
    if BUILD.resolve() != (REPO / "build").resolve():
        env["TEXSYN_BUILD"] = str(BUILD)  # the script's default is build/ beside deploy/
    return subprocess.run(["env", "-i", *(f"{k}={v}" for k, v in env.items()), "bash", "-c", script],
                          cwd=cwd, capture_output=True, text=True, timeout=timeout)


def test_the_readme_cluster_quick_start_runs_the_job_on_the_cluster(data, tmp_path):
    """The README's commands, in a shell that has no TEXSYN_SERVER of its
    own: the synth after `eval "$(deploy/local-cluster.sh start 2)"` is job
    1 of the local coordinator (its log says so), and `texsyn workers`
    finds the 2 workers instead of failing on 127.0.0.1:7070."""
    ref = data / "textures" / "brick.png"
    try:
        p = clean_shell(f"""set -e
eval "$({SCRIPT} start 2)"
texsyn synth --ref {ref} -o out.png --size 96x64 --levels 3 --parity
texsyn workers
texsyn status
{SCRIPT} stop
""", tmp_path)
    finally:  # a failed step leaves the cluster running
        clean_shell(f"{SCRIPT} stop", tmp_path)
    assert p.returncode == 0, p.stdout + p.stderr
    assert re.search(r"^texsyn: out.png in [\d.]+s \(job 1 on 127.0.0.1:\d+ with 2 workers\)$", p.stderr, re.M), p.stderr
    log = (tmp_path / "texsyn-run" / "server.log").read_text()
    assert re.search(r"job 1 done in ", log), log
    assert p.stdout.count(" active ") == 2, p.stdout
    assert re.search(r"^1 +done", p.stdout, re.M), p.stdout
    assert (tmp_path / "out.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "local-cluster: stopped" in p.stdout


def test_the_closing_line_says_where_the_job_ran(texsyn, data, cluster, tmp_path):
    """In-process: the threads; on a coordinator: the job, its address and
    the workers (none: the coordinator scanned alone)."""
    ref = data / "textures" / "grass.png"
    args = ["synth", "--ref", ref, "--size", "48x32", "--levels", "2"]
    p = run(texsyn, *args, "-o", tmp_path / "a.png", "--embedded", "--threads", "3")
    assert re.fullmatch(r"texsyn: \S+a.png in [\d.]+s \(in-process with 3 threads, \w+, [\d.e+]+ comparisons\)",
                        p.stderr.splitlines()[-1]), p.stderr
    cluster.start(0)
    p = run(texsyn, *args, "-o", tmp_path / "b.png", "--server", cluster.server.addr)
    assert re.search(rf"texsyn: \S+b.png in [\d.]+s \(job 1 on {cluster.server.addr} with no workers: "
                     r"the coordinator scanned alone\)\n", p.stderr), p.stderr
    w = cluster.worker()
    cluster.server.stop()
    cluster.restart_server()
    cluster.wait_ready(1)
    p = run(texsyn, *args, "-o", tmp_path / "c.png", "--server", cluster.server.addr)
    assert re.search(rf"\(job 2 on {cluster.server.addr} with 1 worker\)\n", p.stderr), p.stderr
    assert w.alive()


def test_an_output_format_texsyn_does_not_write_is_refused_before_any_work(texsyn, data, cluster, tmp_path):
    """-o big.xyz (no writer), -o x.gif and a --copy-map .bmp (writers
    OpenImageIO has, formats texsyn does not write) and an output without
    an extension: one error naming the option and the formats, exit
    status 2, in-process and on a coordinator alike (with --detach too);
    nothing is written and no job reaches the coordinator."""
    cluster.start(0)
    exts = "use .png, .jpg, .jpeg, .tif, .tiff or .exr"
    cases = [(["-o", tmp_path / "big.xyz"], f"-o {tmp_path}/big.xyz: texsyn does not write .xyz images; {exts}"),
             (["-o", tmp_path / "x.gif"], f"-o {tmp_path}/x.gif: texsyn does not write .gif images; {exts}"),
             (["-o", tmp_path / "a.png", "--copy-map", tmp_path / "c.bmp"],
              f"--copy-map {tmp_path}/c.bmp: texsyn does not write .bmp images; {exts}"),
             (["-o", tmp_path / "a.png", "--usage-map", tmp_path / "usage"],
              f"--usage-map {tmp_path}/usage: the extension names the image format: {exts}")]
    for where in (["--embedded"], ["--server", cluster.server.addr], ["--server", cluster.server.addr, "--detach"]):
        for outs, message in cases:
            p = run(texsyn, "synth", "--ref", data / "textures" / "grass.png", "--size", "48x32", *outs, *where,
                    check=False)
            assert (p.returncode, p.stderr, p.stdout) == (2, f"texsyn synth: {message}\n", ""), (where, p.stderr)
    assert sorted(f.name for f in tmp_path.iterdir() if not f.name.endswith(".log")) == ["spool"]
    assert jobs_listed(cluster.texsyn("status").stdout) == []


def interrupt_after_submission(texsyn, ref, out, *where, env=None):
    """`texsyn synth` of a long job (stderr a pipe, not a terminal),
    interrupted (SIGINT, as Ctrl-C) once it has said which job it
    submitted; returns (exit status, the line naming the job, the last
    line of stderr), the lines between them progress lines."""
    p = subprocess.Popen([str(texsyn), "synth", "--ref", str(ref), "-o", str(out), "--size", "2048x2048", *where],
                         stderr=subprocess.PIPE, text=True, env=dict(os.environ, **(env or {})))
    first = p.stderr.readline()
    p.send_signal(signal.SIGINT)
    *progress, last = p.stderr.read().splitlines(keepends=True) or [""]
    assert all(re.match(r"texsyn synth: job \d+ (queued|level \d of \d, )", line) for line in progress), progress
    return p.wait(timeout=60), first, last


def test_ctrl_c_of_a_cluster_run_names_the_job_that_goes_on(texsyn, data, cluster, tmp_path):
    """The job id is said once submitted; Ctrl-C says the job goes on and
    how to follow and cancel it (with --server when the address came from
    the command line, not $TEXSYN_SERVER), exit status 130. The cancel it
    names returns once the job has stopped: status says canceled and
    delete takes it."""
    cluster.start(1)
    addr = cluster.server.addr
    ref = data / "textures" / "brick.png"
    code, first, rest = interrupt_after_submission(texsyn, ref, tmp_path / "a.png", "--server", addr)
    assert (code, first) == (130, f"texsyn synth: job 1 on {addr}\n"), (code, first, rest)
    assert rest == (f"texsyn synth: interrupted; job 1 keeps running on {addr}: `texsyn watch 1 --server {addr}` "
                    f"follows it, `texsyn cancel 1 --server {addr}` stops it\n"), rest
    code, first, rest = interrupt_after_submission(texsyn, ref, tmp_path / "b.png", env={"TEXSYN_SERVER": addr})
    assert (code, first) == (130, f"texsyn synth: job 2 on {addr}\n"), (code, first, rest)
    assert rest == (f"texsyn synth: interrupted; job 2 keeps running on {addr}: `texsyn watch 2` follows it, "
                    "`texsyn cancel 2` stops it\n"), rest
    states = [r["state"] for r in jobs_listed(cluster.texsyn("status").stdout)]
    assert len(states) == 2 and set(states) <= {"queued", "running"}, states
    for job in ("1", "2"):
        assert cluster.texsyn("cancel", job).stdout == f"job {job} canceled\n"
        assert re.fullmatch(rf"{job} +canceled +canceled by a client", cluster.texsyn("status", job).stdout.splitlines()[0])
        cluster.texsyn("delete", job)
    assert jobs_listed(cluster.texsyn("status").stdout) == []
    assert not (tmp_path / "a.png").exists() and not (tmp_path / "b.png").exists()


def test_fetch_of_outputs_the_job_never_made_fails_naming_them(texsyn, data, cluster, tmp_path):
    """A job submitted without a report or copy map: fetch --report F
    --copy-map F fails naming both and writes nothing, not even -o; the
    outputs it made fetch as they would have been written in-process,
    stylize's --nnf (.raw too) among them, which fetch's --help names."""
    from pnm import oiiotool
    assert "--nnf F (stylize)" in run(texsyn, "fetch", "--help").stdout
    cluster.start(1)
    job = cluster.submit(data / "textures" / "grass.png", "--size", "48x32", "--levels", "2")
    cluster.texsyn("watch", job, "--quiet")
    out, report, copy = tmp_path / "out.png", tmp_path / "r.json", tmp_path / "c.png"
    p = cluster.texsyn("fetch", job, "-o", out, "--report", report, "--copy-map", copy, check=False)
    assert (p.returncode, p.stderr) == (1, f"texsyn fetch: job {job} did not make --report {report}, --copy-map "
                                           f"{copy}: a job makes only the outputs asked for when it was submitted; "
                                           "nothing was written\n"), p.stderr
    assert not out.exists() and not report.exists() and not copy.exists()
    style = tmp_path / "style.png"
    oiiotool(data / "textures" / "grass.png", "--cut", "48x32+100+100", "-o", style)
    for nnf in ("nnf.png", "nnf.raw"):
        args = ["stylize", "--style", style, "--guide", style, style, "--iters", "2", "--quiet"]
        run(texsyn, *args, "-o", tmp_path / "want.png", "--nnf", tmp_path / f"want-{nnf}", "--embedded")
        job = cluster.texsyn(*args, "-o", tmp_path / "x.png", "--nnf", tmp_path / nnf, "--detach").stdout.strip()
        cluster.texsyn("watch", job, "--quiet")
        cluster.texsyn("fetch", job, "-o", tmp_path / "got.png", "--nnf", tmp_path / f"got-{nnf}")
        assert (tmp_path / f"got-{nnf}").read_bytes() == (tmp_path / f"want-{nnf}").read_bytes(), nnf
        assert (tmp_path / "got.png").read_bytes() == (tmp_path / "want.png").read_bytes(), nnf


def test_fetch_converts_to_the_format_its_path_names(texsyn, data, cluster, tmp_path):
    """A job made as PNG and fetched with -o x.tif writes a TIFF with the
    same pixels (before: PNG bytes under a .tif name); -o x.xyz is refused
    as at submit; the NNF's .raw has no conversion: said, nothing written."""
    from pnm import oiiotool, pixels_of
    cluster.start(1)
    job = cluster.submit(data / "textures" / "grass.png", "--size", "48x32", "--levels", "2")
    cluster.texsyn("watch", job, "--quiet")
    png, tif = tmp_path / "got.png", tmp_path / "got.tif"
    cluster.texsyn("fetch", job, "-o", png)
    cluster.texsyn("fetch", job, "-o", tif)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert tif.read_bytes()[:4] in (b"II*\x00", b"MM\x00*")
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    assert pixels_of(png, tmp_path / "a") == pixels_of(tif, tmp_path / "b")
    p = cluster.texsyn("fetch", job, "-o", tmp_path / "x.xyz", check=False)
    assert (p.returncode, p.stderr) == (1, f"texsyn fetch: -o {tmp_path}/x.xyz: texsyn does not write .xyz images; "
                                           "use .png, .jpg, .jpeg, .tif, .tiff or .exr (nothing was written)\n"), p.stderr
    style = tmp_path / "style.png"
    oiiotool(data / "textures" / "grass.png", "--cut", "48x32+100+100", "-o", style)
    args = ["stylize", "--style", style, "--guide", style, style, "--iters", "2", "--quiet"]
    job = cluster.texsyn(*args, "-o", tmp_path / "s.png", "--nnf", tmp_path / "n.raw", "--detach").stdout.strip()
    cluster.texsyn("watch", job, "--quiet")
    p = cluster.texsyn("fetch", job, "-o", tmp_path / "s.png", "--nnf", tmp_path / "n.png", check=False)
    assert p.returncode == 1 and f"job {job} made nnf.raw, and .raw has no conversion" in p.stderr, p.stderr
    assert not (tmp_path / "s.png").exists() and not (tmp_path / "n.png").exists()


def test_a_refused_secret_or_an_address_without_port_says_so(texsyn, data, tmp_path):
    """A wrong secret is named as refused, with the file it came from
    (option or environment), not as a coordinator that may be down; an
    address without a port is named as such; only a connection that fails
    asks whether texsyn-server runs there."""
    from conftest import Daemon
    key, wrong = tmp_path / "key", tmp_path / "wrong"
    for path in (key, wrong):
        path.write_text(os.urandom(24).hex() + "\n")
        path.chmod(0o600)
    server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                     "--secret-file", key], tmp_path / "server.log")
    addr = server.addr
    args = ["synth", "--ref", data / "textures" / "grass.png", "-o", tmp_path / "o.png", "--size", "48x32",
            "--levels", "2"]
    refused = (f"texsyn synth: {addr}: authentication failed: wrong secret (every server, worker and client needs "
               f"the same --secret-file); this client's secret: {wrong}, from ")
    cases = [(["--server", addr, "--secret-file", wrong], {}, refused + "--secret-file"),
             (["--server", addr], {"TEXSYN_SECRET_FILE": str(wrong)}, refused + "$TEXSYN_SECRET_FILE"),
             (["--server", "localhost"], {}, "texsyn synth: --server localhost: need HOST:PORT, e.g. 127.0.0.1:7070"),
             ([], {"TEXSYN_SERVER": "localhost"},
              "texsyn synth: $TEXSYN_SERVER=localhost: need HOST:PORT, e.g. 127.0.0.1:7070"),
             (["--server", "127.0.0.1:1"], {}, "texsyn synth: cannot connect to 127.0.0.1:1: Connection refused "
                                               "(is texsyn-server running at 127.0.0.1:1?)")]
    for where, env, message in cases:
        p = run(texsyn, *args, *where, env=env, check=False)
        assert (p.returncode, p.stderr) == (1, message + "\n(no job was submitted; --embedded runs it here)\n"), \
            (where, env, p.stderr)
    with socket.socket() as held:  # bound, not listening: a connection to the default address is refused
        held.bind(("127.0.0.1", 7070))
        p = run(texsyn, "status", env={"TEXSYN_SERVER": ""}, check=False)
    assert p.stderr == ("texsyn status: cannot connect to 127.0.0.1:7070: Connection refused (is texsyn-server "
                        "running at 127.0.0.1:7070, the default: no --server, no $TEXSYN_SERVER?)\n"), p.stderr
    assert jobs_listed(run(texsyn, "status", "--server", addr, "--secret-file", key).stdout) == []
    assert not (tmp_path / "o.png").exists()


def test_progress_counts_levels_one_way_and_reaches_logs_without_a_terminal(texsyn, data, cluster, tmp_path):
    """Without a terminal (a batch job's log) a plain line as each level
    starts, "level K of L" with 1 the coarsest, in-process and on a
    coordinator, for synth and watch; the bar on a terminal counts the same
    way; --quiet leaves stderr empty."""
    import pty
    ref = data / "textures" / "grass.png"
    args = ["synth", "--ref", ref, "--size", "96x64", "--levels", "3"]
    line = r"texsyn (synth|watch): {job}level {k} of 3, [\d.]+% of the work, ETA (\?|[\d.]+s){workers}"

    def levels(stderr, job="", workers=""):
        got = [int(m.group(2)) for m in re.finditer(line.format(job=job, k=r"(\d)", workers=workers), stderr)]
        assert got == [1, 2, 3], stderr
        return stderr

    err = levels(run(texsyn, *args, "-o", tmp_path / "a.png", "--embedded").stderr)
    assert len(err.splitlines()) == 4 and err.splitlines()[-1].startswith("texsyn: "), err
    assert run(texsyn, *args, "-o", tmp_path / "q.png", "--embedded", "--quiet").stderr == ""
    cluster.start(1)
    addr = cluster.server.addr
    err = levels(run(texsyn, *args, "-o", tmp_path / "b.png", "--server", addr).stderr, "job 1 ", ", 1 worker")
    assert err.splitlines()[0] == f"texsyn synth: job 1 on {addr}", err
    job = cluster.submit(ref, "--size", "96x64", "--levels", "3")
    levels(cluster.texsyn("watch", job).stderr, f"job {job} ", ", 1 worker")
    # On a terminal: the bar, redrawn in place, with the same numbering.
    main, sub = pty.openpty()
    p = subprocess.run([str(texsyn), *map(str, args), "-o", str(tmp_path / "c.png"), "--embedded"],
                       stderr=sub, stdout=subprocess.DEVNULL, timeout=120)
    os.close(sub)
    shown = b""
    while True:
        try:
            chunk = os.read(main, 65536)
        except OSError:
            break
        if not chunk:
            break
        shown += chunk
    os.close(main)
    text = shown.decode()
    assert p.returncode == 0 and "\rlevel 1 of 3 " in text and "\rlevel 3 of 3 100% of blocks" in text, text
    assert "texsyn synth: level" not in text and "(1 of 3)" not in text, text


def test_every_program_says_its_version_and_the_wire_protocol_it_speaks():
    """--version: the same release for the three programs, and the protocol
    version their frames carry (the third byte of every frame header)."""
    from conftest import FRAME_START
    lines = [run(BUILD / prog, "--version").stdout for prog in ("texsyn", "texsyn-server", "texsyn-worker")]
    release = re.fullmatch(rf"texsyn (\d+\.\d+\.\d+) \(wire protocol {FRAME_START[2]}\)\n", lines[0])
    assert release, lines
    assert lines[1:] == [f"texsyn-server {release.group(1)} (wire protocol {FRAME_START[2]})\n",
                         f"texsyn-worker {release.group(1)} (wire protocol {FRAME_START[2]})\n"], lines


def test_a_mistyped_command_or_option_gets_the_closest_one(texsyn):
    """Commands, and the options of every command's table: the closest
    within two edits, or none; an option's missing value or a value given
    to a flag said as such."""
    cases = [(["synht"], "texsyn: unknown command 'synht'; did you mean 'synth'?\n"),
             (["stauts"], "texsyn: unknown command 'stauts'; did you mean 'status'?\n"),
             (["frobnicate"], "texsyn: unknown command 'frobnicate'\n"),
             (["synth", "--levles", "3"],
              "texsyn synth: unknown option --levles; did you mean --levels? (see texsyn synth --help)\n"),
             (["synth", "--levles=3"],
              "texsyn synth: unknown option --levles=3; did you mean --levels? (see texsyn synth --help)\n"),
             (["synth", "--levels"], "texsyn synth: --levels needs a value (see texsyn synth --help)\n"),
             (["synth", "--parity=1"], "texsyn synth: --parity takes no value (see texsyn synth --help)\n"),
             (["synth", "-x"], "texsyn synth: unknown option -x (see texsyn synth --help)\n"),
             (["synth", "--ref", "a.png", "-o"], "texsyn synth: -o needs a value (see texsyn synth --help)\n")]
    # Every command's table: (command, typo, the option meant).
    for cmd, typo, meant in [("stylize", "stlye", "style"), ("energy", "sampel", "sample"), ("apply-nnf", "nff", "nnf"),
                             ("segment", "trian", "train"), ("aerial", "clases", "classes"),
                             ("status", "sevrer", "server"), ("quality", "imgae", "image"), ("modbus", "sett", "set")]:
        cases.append(([cmd, f"--{typo}", "x"], f"texsyn {cmd}: unknown option --{typo}; did you mean --{meant}? "
                                               f"(see texsyn {cmd} --help)\n"))
    for args, message in cases:
        p = run(texsyn, *args, check=False)
        first = p.stderr.splitlines(keepends=True)[0]
        assert (p.returncode, first) == (2, message), (args, p.stderr)


def test_texsyn_help_is_the_command_table(texsyn):
    """`texsyn --help` lists every command once, one line each, and every
    command it lists answers its own --help (the alias run as synth); no
    command at all shows the list on stderr, exit status 2."""
    p = run(texsyn, "--help")
    lines = p.stdout.splitlines()
    assert lines[0] == "usage: texsyn COMMAND [options]   (texsyn COMMAND --help for details)", p.stdout
    names = [re.match(r"  (\S+) +\S", line).group(1) for line in lines[1:]]
    assert names == ["synth", "aerial", "catalogue", "stylize", "energy", "apply-nnf", "segment", "video", "flicker",
                     "quality",
                     "shuffle", "simd",
                     "params", "status", "watch", "fetch", "cancel", "delete", "workers", "modbus", "help",
                     "--version"], names
    for name in names:
        q = run(texsyn, name, "--help")
        assert q.stdout.startswith("usage: texsyn") or name == "--version", (name, q.stdout)
    assert run(texsyn, "run", "--help").stdout == run(texsyn, "synth", "--help").stdout
    assert run(texsyn, "help").stdout == run(texsyn, "-h").stdout == p.stdout
    bare = run(texsyn, check=False)
    assert (bare.returncode, bare.stderr, bare.stdout) == (2, p.stdout, "")


def test_energy_prints_one_json_object_as_quality_does(texsyn, data, tmp_path):
    """Both measures print one JSON object on stdout and nothing else."""
    from pnm import oiiotool
    style = tmp_path / "style.png"
    oiiotool(data / "textures" / "grass.png", "--cut", "48x32+100+100", "-o", style)
    energy = run(texsyn, "energy", "--style", style, "--guide", style, style, "--image", style, "--embedded",
                 "--quiet").stdout
    quality = run(texsyn, "quality", "--ref", style, "--image", style, "--samples", "50").stdout
    for out in (energy, quality):
        assert out.count("\n") == 1 and isinstance(json.loads(out), dict), out
    assert json.loads(energy)["samples"] == 48 * 32 and json.loads(energy)["coverage"] == 1, energy


def test_the_local_clusters_run_directory_is_ignored_by_git():
    """deploy/local-cluster.sh leaves its pids, logs and spool in
    ./texsyn-run by default: .gitignore keeps them out of `git status`."""
    default = re.search(r"^run=\$\{TEXSYN_RUN:-([^}]+)\}$", SCRIPT.read_text(), re.M).group(1)
    assert f"/{default}/" in (REPO / ".gitignore").read_text().splitlines(), default
