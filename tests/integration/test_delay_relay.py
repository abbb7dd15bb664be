"""bench/delay_relay, the user-space delay bench/netem.py falls back to
where the kernel has no netem qdisc: it must forward a TCP stream exactly
both ways (byte for byte, in order, with the half-close) and hold every
chunk at least the delay asked for, which it also reports."""
import json
import os
import re
import socket
import subprocess
import threading
import time

import pytest

from conftest import BUILD

RELAY = BUILD / "bench" / "delay_relay"
DELAY_US = 2000  # one way: a round trip gains at least 4 ms


def start_relay(target, delay_us):
    p = subprocess.Popen([str(RELAY), "--listen", "127.0.0.1:0", "--target", target, "--delay-us", str(delay_us)],
                         stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    m = re.search(r"listening on (\S+)", p.stdout.readline())
    assert m, f"delay_relay did not start: {p.stderr.read()}"
    return p, m.group(1)


def connect(addr):
    host, port = addr.rsplit(":", 1)
    s = socket.create_connection((host, int(port)))
    s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return s


def recv_all(s):
    parts = []
    while True:
        b = s.recv(1 << 16)
        if not b:
            return b"".join(parts)
        parts.append(b)


def recv_exact(s, n):
    b = b""
    while len(b) < n:
        part = s.recv(n - len(b))
        assert part, "the relay closed the stream early"
        b += part
    return b


@pytest.fixture
def server():
    """A loopback server that runs one handler per accepted connection."""
    lsock = socket.socket()
    lsock.bind(("127.0.0.1", 0))
    lsock.listen(4)
    box = {}

    def serve():
        conn, _ = lsock.accept()
        box["result"] = box["handler"](conn)
        conn.close()

    def run(handler):
        box["handler"] = handler
        t = threading.Thread(target=serve, daemon=True)
        t.start()
        return t, box

    yield "127.0.0.1:%d" % lsock.getsockname()[1], run
    lsock.close()


@pytest.fixture
def relay_bin():
    assert RELAY.exists(), f"{RELAY} is missing: run make first"
    return RELAY


@pytest.mark.sanitize
def test_forwards_bytes_exactly_both_ways(relay_bin, server):
    """6 MB up and 5 MB down at once, random bytes: each side gets exactly
    what the other sent, and the half-close after it; the relay ends
    cleanly on SIGTERM (under ASan: no error, no leak)."""
    up, down = os.urandom(6 << 20), os.urandom(5 << 20)
    addr, run = server

    def handler(conn):
        sender = threading.Thread(target=lambda: (conn.sendall(down), conn.shutdown(socket.SHUT_WR)))
        sender.start()
        got = recv_all(conn)
        sender.join()
        return got

    t, box = run(handler)
    relay, raddr = start_relay(addr, 200)
    try:
        s = connect(raddr)
        sender = threading.Thread(target=lambda: (s.sendall(up), s.shutdown(socket.SHUT_WR)))
        sender.start()
        got_down = recv_all(s)
        sender.join()
        t.join(timeout=60)
        s.close()
        assert got_down == down
        assert box["result"] == up
    finally:
        relay.terminate()
        out, err = relay.communicate(timeout=10)
    assert relay.returncode == 0, err
    stats = json.loads(out.strip().splitlines()[-1])
    assert stats["bytes"] == len(up) + len(down)


def test_adds_at_least_the_delay(relay_bin, server):
    """Small request/response round trips through the relay take at least
    2 x the one-way delay, and the relay's own report of the achieved
    delay (median and p99 per chunk) is at least the delay asked for."""
    addr, run = server
    rounds = 20

    def handler(conn):
        for _ in range(rounds):
            conn.sendall(recv_exact(conn, 16))

    t, _ = run(handler)
    relay, raddr = start_relay(addr, DELAY_US)
    try:
        s = connect(raddr)
        rtts = []
        for i in range(rounds):
            msg = i.to_bytes(16, "little")
            t0 = time.perf_counter()
            s.sendall(msg)
            assert recv_exact(s, 16) == msg
            rtts.append(time.perf_counter() - t0)
        t.join(timeout=30)
        s.close()
        relay.stdin.write("stats\n")
        relay.stdin.flush()
        stats = json.loads(relay.stdout.readline())
    finally:
        relay.terminate()
        relay.communicate(timeout=10)
    assert min(rtts) >= 2 * DELAY_US / 1e6
    assert stats["chunks"] == 2 * rounds
    assert stats["median_us"] >= DELAY_US and stats["p99_us"] >= DELAY_US


def test_delay_changes_on_command_and_bad_commands_are_refused(relay_bin, server):
    addr, _ = server
    relay, _ = start_relay(addr, 0)
    try:
        for cmd, answer in (("delay 250\n", "ok delay 250.0"), ("delay -1\n", "error: delay wants"),
                            ("delay 5x\n", "error: delay wants"), ("jump\n", "error: unknown command")):
            relay.stdin.write(cmd)
            relay.stdin.flush()
            assert relay.stdout.readline().startswith(answer), cmd
        relay.stdin.write("stats\n")
        relay.stdin.flush()
        assert json.loads(relay.stdout.readline()) == {"delay_us": 250.0, "chunks": 0, "bytes": 0}
    finally:
        relay.terminate()
        relay.communicate(timeout=10)


def test_refuses_bad_options(relay_bin):
    for args, msg in ((["--listen", "127.0.0.1:0", "--target", "nohostport"], "cannot resolve --target"),
                      (["--listen", "127.0.0.1:0", "--target", "127.0.0.1:1", "--delay-us", "lots"], "--delay-us"),
                      (["--listen", "127.0.0.1:0"], "usage")):
        p = subprocess.run([str(RELAY), *args], capture_output=True, text=True, timeout=10)
        assert p.returncode == 2 and msg in p.stderr, args
