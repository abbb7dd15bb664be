"""The operations page (texsyn-server --http): the status page loaded in a
real headless browser (Debian's chromium) while a job runs, /metrics read
with the Prometheus client library's own parser (Debian's
python3-prometheus-client), the thumbnails, and who may see what."""
import base64
import json
import re
import shutil
import signal
import struct
import subprocess
import tempfile
import time
import urllib.error
import urllib.request

import pytest
from prometheus_client.parser import text_string_to_metric_families

from conftest import BUILD, Daemon, run

# Stalled workers hold a batch, and with it the job, as long as the test
# needs: no heartbeat drops them, no deadline passes.
STALL_ARGS = ["--calibrate-ms", "50", "--heartbeat", "0", "--batch-timeout", "3600"]
JOB_SIZE = (320, 240)
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def ref_of(data):
    return data / "textures" / "brick.png"


def get(url, auth=None, method="GET"):
    """(status, headers, body) of one request; auth is the Authorization value."""
    req = urllib.request.Request(url, method=method)
    if auth is not None:
        req.add_header("Authorization", auth)
    try:
        with urllib.request.urlopen(req, timeout=30) as r:
            return r.status, r.headers, r.read()
    except urllib.error.HTTPError as e:
        return e.code, e.headers, e.read()


def http_addr(server):
    return server.wait_log(r"http page on (\S+?),").group(1)


def status(base):
    code, _, body = get(base + "/status.json")
    assert code == 200, body
    return json.loads(body)


def job_of(st, job):
    return next(j for j in st["jobs"] if j["id"] == int(job))


def wait_until(what, pred, timeout=120):
    deadline = time.time() + timeout
    while True:
        v = pred()
        if v:
            return v
        assert time.time() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)


def scrape(base):
    """The /metrics families by name, through prometheus_client's parser."""
    code, headers, body = get(base + "/metrics")
    assert code == 200 and headers["Content-Type"].startswith("text/plain; version=0.0.4"), body
    return {f.name: f for f in text_string_to_metric_families(body.decode())}


def value(families, name, **labels):
    for s in families[name].samples:
        if all(s.labels.get(k) == v for k, v in labels.items()):
            return s.value
    raise AssertionError(f"no sample {name}{labels}")


def chromium_dom(url):
    exe = shutil.which("chromium")
    if exe is None:
        pytest.fail("chromium is not installed: it is Debian's chromium, which deploy/install-deps.sh installs",
                    pytrace=False)
    with tempfile.TemporaryDirectory() as profile:
        p = subprocess.run([exe, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                            "--disable-background-networking", "--disable-component-update", "--disable-sync",
                            f"--user-data-dir={profile}", "--dump-dom", url],
                           capture_output=True, text=True, timeout=120)
    assert p.returncode == 0 and "</html>" in p.stdout, p.stderr[-2000:]
    return p.stdout


def png_size(body):
    assert body[:8] == PNG_MAGIC and body[12:16] == b"IHDR", body[:32]
    return struct.unpack(">II", body[16:24])


def test_page_in_chromium_metrics_grow_and_thumbnail(data, cluster, tmp_path):
    cluster.worker(1)
    cluster.worker(1)
    cluster.start(0, 1, *STALL_ARGS, "--http", "127.0.0.1:0", "--workers",
                  ",".join(w.addr for w in cluster.workers))
    base = "http://" + http_addr(cluster.server)
    w, h = JOB_SIZE
    job = cluster.submit(ref_of(data), "--size", f"{w}x{h}")
    wait_until("the job to make progress",
               lambda: job_of(status(base), job)["state"] == "running" and job_of(status(base), job)["permille"] > 0)

    # /metrics: counters grow between two scrapes while the job runs.
    first = scrape(base)
    assert value(first, "texsyn_jobs", state="running") == 1
    assert value(first, "texsyn_current_job_id") == int(job)
    def grown():
        m = scrape(base)
        return m if value(m, "texsyn_queries") > value(first, "texsyn_queries") else None

    second = wait_until("queries to grow", grown)
    assert value(second, "texsyn_jobs", state="running") == 1, "the job ended between the scrapes"
    assert value(second, "texsyn_batches") > value(first, "texsyn_batches")
    assert first["texsyn_queries"].type == "counter" and first["texsyn_batches"].type == "counter"
    for wk in cluster.workers:
        assert value(second, "texsyn_worker_state", worker=wk.addr, state="ready") == 1
        assert 0 < value(second, "texsyn_worker_slice_share_ratio", worker=wk.addr) < 1
        assert value(second, "texsyn_worker_calibrated_bytes_per_second", worker=wk.addr) > 0

    # The page in chromium, with the job held running: both workers stalled.
    for wk in cluster.workers:
        wk.proc.send_signal(signal.SIGSTOP)
    try:
        dom = chromium_dom(base + "/")
    finally:
        for wk in cluster.workers:
            wk.proc.send_signal(signal.SIGCONT)
    row = re.search(rf'<tr class="job running" id="job-{job}">(.*?)</tr>', dom, re.S)
    assert row, dom
    progress = re.search(r'<progress max="1000" value="(\d+)"', row.group(1))
    assert progress and int(progress.group(1)) > 0, row.group(1)
    assert re.search(r"level \d+ of \d+", row.group(1)) and "<td>mrf</td>" in row.group(1), row.group(1)
    pool = re.search(r'<table id="pool">(.*?)</table>', dom, re.S).group(1)
    for wk in cluster.workers:
        assert re.search(rf'<tr class="worker ready"><td>{re.escape(wk.addr)}</td>', pool), pool
    assert pool.count("%</td>") == 2, pool  # a slice share each

    # Finished: a thumbnail of the result's aspect ratio, made once.
    wait_until("the job to finish", lambda: job_of(status(base), job)["state"] == "done")
    code, headers, body = get(f"{base}/jobs/{job}/thumb.png")
    assert code == 200 and headers["Content-Type"] == "image/png"
    assert png_size(body) == (160, 120)
    cached = tmp_path / "spool" / "jobs" / job / "thumb.png"
    assert cached.read_bytes() == body
    assert get(f"{base}/jobs/{job}/thumb.png")[2] == body
    code, _, page = get(base + "/")
    assert f'<img src="/jobs/{job}/thumb.png"'.encode() in page


def secret(tmp_path):
    path = tmp_path / "secret"
    path.write_text("s3cret-" + tmp_path.name + "\n")
    path.chmod(0o600)
    return path, path.read_text().strip()


def basic(password, user="ops"):
    return "Basic " + base64.b64encode(f"{user}:{password}".encode()).decode()


@pytest.mark.sanitize
def test_secret_guards_every_page(data, cluster, tmp_path):
    key, text = secret(tmp_path)
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                             "--secret-file", key, "--http", ":0"], tmp_path / "server.log")
    base = "http://" + http_addr(cluster.server)
    assert base.startswith("http://127.0.0.1:")  # :PORT is loopback
    run(BUILD / "texsyn", "synth", "--server", cluster.server.addr, "--secret-file", key, "--ref", ref_of(data),
        "-o", tmp_path / "out.png", "--size", "96x64", "--levels", "3", "--quiet")
    pages = ["/", "/status.json", "/metrics", "/jobs/1/thumb.png", "/jobs/1/small.png", "/jobs/99/thumb.png"]
    for auth in (None, basic("wrong"), "Bearer wrong", "Bearer " + text + "x", "Digest abc", basic(text)[:-4]):
        for page in pages:
            code, headers, body = get(base + page, auth)
            assert code == 401, (page, auth, code)
            assert headers["WWW-Authenticate"].startswith("Basic realm="), headers
            assert b"mrf" not in body and b"jobs" not in body, body  # no job data
    good = (basic(text), basic(text, user=""), "Bearer " + text)
    for auth in good:
        st = json.loads(get(base + "/status.json", auth)[2])
        assert [(j["id"], j["engine"], j["state"]) for j in st["jobs"]] == [(1, "mrf", "done")]
        code, _, body = get(base + "/jobs/1/thumb.png", auth)
        assert code == 200 and png_size(body) == (96, 64)
        code, _, body = get(base + "/jobs/1/small.png", auth)
        assert code == 200 and png_size(body) == (64, 43)  # 96x64 at 64 px long: 42.67 rounds to 43
        assert get(base + "/metrics", auth)[0] == 200
    for page, code in (("/nope", 404), ("/jobs/99/thumb.png", 404), ("/jobs/0/thumb.png", 404),
                       ("/jobs/01/thumb.png", 404), ("/jobs/x/thumb.png", 404), ("/jobs/1/thumb.gif", 404),
                       ("/jobs/18446744073709551616/thumb.png", 404)):
        assert get(base + page, good[0])[0] == code, page
    for method in ("POST", "PUT", "DELETE"):
        code, headers, _ = get(base + "/", good[0], method=method)
        assert code == 405 and headers["Allow"] == "GET, HEAD", method
    code, _, body = get(base + "/", good[0], method="HEAD")
    assert code == 200 and body == b""


def non_loopback_ipv4():
    out = subprocess.run(["hostname", "-I"], capture_output=True, text=True, timeout=10).stdout
    return next((a for a in out.split() if "." in a and not a.startswith("127.")), None)


def test_without_secret_only_loopback_peers(cluster, tmp_path):
    ip = non_loopback_ipv4()
    if ip is None:
        pytest.skip("this machine has no non-loopback IPv4 address")
    cluster.server = Daemon([BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool",
                             "--http", "0.0.0.0:0"], tmp_path / "server.log")
    port = http_addr(cluster.server).rsplit(":", 1)[1]
    assert "WARNING" in cluster.server.read_log()
    code, _, body = get(f"http://{ip}:{port}/status.json")
    assert code == 403 and b"protected mode" in body and b"jobs" not in body, body
    assert get(f"http://127.0.0.1:{port}/status.json")[0] == 200


def test_bad_http_option_is_refused(tmp_path):
    for arg, why in (("nope", "port must be 0..65535"), ("127.0.0.1:70000", "port must be 0..65535")):
        p = run(BUILD / "texsyn-server", "--listen", "127.0.0.1:0", "--spool", tmp_path / "spool", "--http", arg,
                check=False, timeout=30)
        assert p.returncode != 0 and f"--http {arg}" in p.stderr and why in p.stderr, p.stderr
