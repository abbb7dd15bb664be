"""A hostile peer between texsyn-server and one texsyn-worker (issue 25).

HostileProxy listens on a loopback port the coordinator dials as a worker
(`--workers`), dials the worker behind it for every connection, and reads
the frames both ways (proto/PROTOCOL.md: a 12-byte header "TS", version,
type, u32 length, u32 id; 'M' pieces reassembled). Every frame the
coordinator sends is forwarded at once, and remembered as a request owed
an answer (the worker answers in request order). Every frame the worker
sends is a reply the proxy may damage before the coordinator sees it, as a
schedule of Rules says:

    Rule("V", nth=3, action="dup")              the 3rd 'V' reply, twice
    Rule("R", side="request", where=lambda r: r.info.get("op") == 2,
         action="kill")                         SIGKILL the worker on the
                                                next-level 'R' it is sent

A rule counts the frames of its type (and `where`) from the moment the
schedule is armed, and fires on the nth one: triggers are frames, never
wall time. Actions on replies: pass, dup, reorder (swap with the next
reply), delay (hold the stream `ms`), drop (optionally cut the link
`cut_after` seconds later), truncate (`how`="payload": a shorter body with
a consistent header; "half": half the frame's bytes, then the link is cut,
or the worker killed with then="kill"), forge (inject a frame built by a
Forge `place`d before, after or instead of the reply; `hold` seconds before
the real one follows), cut (close the link), kill / stop (SIGKILL or SIGSTOP
the worker, SIGCONT after `seconds`), signal (any signal to any process:
`target`, `sig`, `resume_after`), call (a function of the link and frame).
On requests: kill, stop, signal, cut, call.

With joining=True the roles turn: a worker started with --join connects to
the proxy, which dials the coordinator (its `target`); Link.peer is then
the address the coordinator names that worker by.

Stdlib only (/usr/bin/python3), threads and blocking sockets: each link
has a pump per direction, and a delay holds its direction's stream, as a
slow worker would.
"""
import collections
import os
import random
import select
import signal
import socket
import struct
import threading
import time

HEADER = struct.Struct("<2sBcII")  # magic, version, type, payload length, id
MAGIC, VERSION = b"TS", 8  # proto/frame.h TS_PROTO_VERSION
PIECE = struct.Struct("<cQQ")  # an 'M' piece: the message's type, total, offset

NO_INDEX = 0xFFFFFFFF


def frame_bytes(ftype, fid, payload=b""):
    return HEADER.pack(MAGIC, VERSION, ftype.encode(), len(payload), fid & 0xFFFFFFFF) + payload


class Frame:
    """One frame (or one message reassembled from 'M' pieces): its type
    letter, id and payload; `info`, for requests, what parse_request read
    of it."""

    __slots__ = ("type", "id", "payload", "info", "raw", "request")

    def __init__(self, ftype, fid, payload, raw=None):
        self.type, self.id, self.payload, self.info, self.request = ftype, fid, payload, {}, None
        self.raw = raw if raw is not None else frame_bytes(ftype, fid, payload)

    def __repr__(self):
        return f"'{self.type}' id {self.id:#x} ({len(self.payload)} bytes)"


class ProtocolViolation(Exception):
    pass


class FrameReader:
    """Frames out of a byte stream fed in pieces of any size; 'M' pieces
    come out as the message they carry, once its last piece is in."""

    def __init__(self):
        self.buf = bytearray()
        self.piece = None  # (type, id, total, bytearray) of a message in pieces

    def feed(self, data):
        self.buf += data

    def frames(self):
        out = []
        while len(self.buf) >= HEADER.size:
            magic, version, ftype, length, fid = HEADER.unpack_from(self.buf)
            if magic != MAGIC or version != VERSION:
                raise ProtocolViolation(f"bad frame start {bytes(self.buf[:4])!r}")
            if len(self.buf) < HEADER.size + length:
                break
            raw = bytes(self.buf[:HEADER.size + length])
            del self.buf[:HEADER.size + length]
            f = Frame(ftype.decode("latin-1"), fid, raw[HEADER.size:], raw)
            if f.type == "M":
                f = self.join_piece(f)
            if f is not None:
                out.append(f)
        return out

    def join_piece(self, f):
        inner, total, offset = PIECE.unpack_from(f.payload)
        if offset == 0:
            self.piece = (inner.decode("latin-1"), f.id, total, bytearray())
        t, fid, total, body = self.piece
        body += f.payload[PIECE.size:]
        if len(body) < total:
            return None
        self.piece = None
        return Frame(t, fid, bytes(body), raw=b"")  # its bytes went as pieces


# ---- what the coordinator asks ---------------------------------------------

def slice_classes(body):
    """What an 'N' payload says of the slice (PROTOCOL.md, `N`): [(count,
    i0, i1)] per class - the set's vectors of the class and this slice's
    range of them - and the bytes of one vector (the window's offsets
    times the planes each part reads)."""
    nfine, ncoarse = body[12], body[13]
    off, noffs = 18, []
    for n in (nfine, ncoarse):
        noffs.append(struct.unpack_from("<H", body, off + 8)[0] if n else 0)
        if n:
            off += 10 + 4 * noffs[-1]
    nparts = body[off]
    vbytes = sum(noffs[body[off + 1 + 7 * k]] * body[off + 3 + 7 * k] for k in range(nparts))
    off += 1 + 7 * nparts
    off += 1 + (noffs[0] if body[off] else 0)  # the known flags
    off += 16
    nclass, labelled = struct.unpack_from("<HB", body, off)
    off += 4
    if labelled == 2:  # the labels as a tile: its sides, then its bytes
        off += 2 + body[off] * body[off + 1]
    return [struct.unpack_from("<III", body, off + 12 * c) for c in range(nclass)], vbytes


def parse_request(f):
    """What a request says that a forged answer needs (a dict)."""
    p, info = f.payload, {}
    try:
        if f.type == "V":
            info["set"], info["gen"], info["image"], info["seq"], nplace = struct.unpack_from("<IIIQI", p)
            info["nq"] = struct.unpack_from("<I", p, 24 + 8 * nplace)[0]
        elif f.type == "N":
            info["set"], info["gen"], info["image"] = struct.unpack_from("<III", p)
            info["classes"], info["vector_bytes"] = slice_classes(p)
        elif f.type == "R":
            info["image"], info["op"], info["seq"] = struct.unpack_from("<IBQ", p)
        elif f.type in "GQ" and len(p) >= 4:
            info["set"] = struct.unpack_from("<I", p)[0]
        elif f.type == "T":
            (info["set"], info["image"], info["seq"], info["tw"], info["th"], _, _, info["pass"],
             ntiles) = struct.unpack_from("<IIQIIQQII", p)
            info["tiles"] = struct.unpack_from(f"<{ntiles}I", p, 48)
        elif f.type == "C":
            info["millis"] = struct.unpack_from("<I", p)[0]
    except struct.error:
        pass  # a short request: the worker will say so
    return info


# ---- forged replies ----------------------------------------------------------

def reply_payload(rtype, req, rng, body="plausible"):
    """The payload of a reply of type rtype to request req (a Frame, or None
    for an unsolicited one), plausible or damaged as `body` says:
    plausible, wrong-set, wrong-gen, wrong-nq (a 'V' or 'T' answer's count
    off by one), out-of-slice, out-of-set ('V': an index outside the
    worker's slice, or past the set; 'T': an entry that is no patch
    centre), garbage (random bytes)."""
    info = req.info if req is not None and req.type == rtype else {}
    if body == "garbage":
        return rng.randbytes(rng.choice([0, 1, 3, 7, 16, 40]))
    set_id, gen = info.get("set", rng.randrange(1, 64)), info.get("gen", rng.randrange(1, 8))
    if body == "wrong-set":
        set_id += 1
    if body == "wrong-gen":
        gen += 1
    if rtype == "R":
        return struct.pack("<I", info.get("image", set_id))
    if rtype == "N":
        return struct.pack("<IIQ", set_id, gen, rng.randrange(1, 1 << 16))
    if rtype in "G":
        return struct.pack("<I", set_id)
    if rtype in "QH":
        return b""
    if rtype == "C":
        return struct.pack("<QQIQ", 1 << 20, 1 << 20, 1 << 16, 1 << 20)
    if rtype == "E":
        text = b"a hostile peer's error"
        return struct.pack("<iH", -5, len(text)) + text
    if rtype == "T":
        n = pass_entries(info) if "tiles" in info else 64 * 64
        if body == "wrong-nq":
            n += rng.choice([-1, 1])
        # (2, 2) is a patch centre of any source (5x5 patches: the tests');
        # (0, 0) is none.
        entry = b"\0\0\0\0" if body in ("out-of-slice", "out-of-set") else b"\2\0\2\0"
        pass_no = info.get("pass", 0) + (body == "wrong-gen")  # a pass has no generation: another pass
        return struct.pack("<IIQI", set_id, pass_no, 1000, n) + entry * n
    if rtype == "V":
        nq = info.get("nq", rng.randrange(1, 64))
        if body == "wrong-nq":
            nq += rng.choice([-1, 1]) if nq > 1 else 1
        index = forged_index(req, rng, body)
        results = b"".join(struct.pack("<IQ", index, 0) for _ in range(nq))
        return struct.pack("<IIIQQ", set_id, gen, nq, 1000, nq) + results
    return rng.randbytes(8)


def pass_entries(info):
    """The field entries a 'T' request's tiles hold: 64x64 tiles, row-major
    over its tw x th field, cut at the edges (PROTOCOL.md, `T`)."""
    ntx = (info["tw"] + 63) // 64
    n = 0
    for t in info["tiles"]:
        x0, y0 = t % ntx * 64, t // ntx * 64
        n += (min(x0 + 64, info["tw"]) - x0) * (min(y0 + 64, info["th"]) - y0)
    return n


def forged_index(req, rng, body):
    """A vector index for a forged 'V' answer: in the worker's slice
    (plausible), in the set but outside the slice, or past the set."""
    classes = req.info.get("slice") if req is not None else None
    if not classes:
        return rng.randrange(0, 64) if body != "out-of-set" else NO_INDEX - 1
    total = sum(c for c, _, _ in classes)
    ranges, base = [], 0
    for count, i0, i1 in classes:
        ranges.append((base + i0, base + i1))
        base += count
    if body == "out-of-set":
        return total + rng.randrange(0, 1000)
    inside = [i for a, b in ranges for i in (a, b - 1) if b > a]
    if body == "out-of-slice":
        outside = [i for i in range(0, total, max(1, total // 97)) if not any(a <= i < b for a, b in ranges)]
        if outside:
            return rng.choice(outside)
        return total + 1  # the slice is the whole set: nothing inside it is outside
    return rng.choice(inside) if inside else 0


class Forge:
    """Builds a forged reply when a rule fires: its type, which request's
    id it carries (`ident`: "trigger", the id of the frame that fired the
    rule; "oldest", the oldest request still owed an answer; "answered",
    one answered already; "unsent", one no request carries yet; "random")
    and its body (see reply_payload)."""

    def __init__(self, rtype, ident="trigger", body="plausible", seed=0):
        self.rtype, self.ident, self.body = rtype, ident, body
        self.rng = random.Random(seed)

    def build(self, link, trigger):
        fid, req = link.pick_id(self.ident, trigger, self.rng)
        return frame_bytes(self.rtype, fid, reply_payload(self.rtype, req, self.rng, self.body))

    def __repr__(self):
        return f"forged '{self.rtype}' ({self.ident} id, {self.body})"


# ---- the schedule ---------------------------------------------------------

class Rule:
    """One action of a schedule: on the nth frame of type `on` (a letter,
    or "*" for any) that the worker sends (side="reply") or is sent
    (side="request"), and that `where(frame)` accepts."""

    def __init__(self, on, nth=1, action="pass", side="reply", where=None, **params):
        self.on, self.nth, self.action, self.side, self.where = on, nth, action, side, where
        self.params = params
        self.seen = 0
        self.fired = threading.Event()  # the action began
        self.done = threading.Event()  # and ended (a delayed frame went on)
        self.note = ""

    def matches(self, side, f):
        if side != self.side or (self.on != "*" and f.type != self.on):
            return False
        return self.where is None or self.where(f)

    def __repr__(self):
        extra = ", ".join(f"{k}={v!r}" for k, v in self.params.items() if k not in ("target", "fn"))
        return f"{self.action} the {self.side} '{self.on}' #{self.nth}" + (f" ({extra})" if extra else "")


class Victim:
    """A process the proxy may signal: a conftest Daemon (its Popen records
    the signals, so check_daemons knows they were the test's) or a pid."""

    def __init__(self, proc):
        self.proc = proc

    def send(self, sig):
        if hasattr(self.proc, "proc"):
            proc = self.proc.proc
        else:
            proc = self.proc
        try:
            if hasattr(proc, "send_signal"):
                proc.send_signal(sig)
            else:
                os.kill(proc, sig)
        except (ProcessLookupError, OSError):
            pass


def shut(*socks):
    for s in socks:
        try:
            s.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass


class Link:
    """One coordinator connection through the proxy, and what it owes:
    the requests sent and not answered yet, in order."""

    def __init__(self, proxy, coord, worker, number):
        self.proxy, self.coord, self.worker, self.number = proxy, coord, worker, number
        self.lock = threading.Lock()
        self.outstanding = collections.deque()  # requests owed an answer, oldest first
        self.answered = collections.deque(maxlen=64)
        self.last_id = 0
        self.slices = {}  # set id -> its classes in the worker's slice ('N')
        self.closed = False
        self.unanswered_start = False  # the coordinator's first frame answers the worker's 'I'
        self.peer = None  # the worker's address as the coordinator names it

    def close(self):
        self.closed = True
        shut(self.coord, self.worker)

    def note_request(self, f):
        f.info = parse_request(f)
        if self.unanswered_start:
            self.unanswered_start = False
            return
        if f.type == "N" and "classes" in f.info:
            self.slices[f.info["set"]] = f.info["classes"]
        if f.type == "V":
            f.info["slice"] = self.slices.get(f.info.get("set"))
        with self.lock:
            self.outstanding.append(f)
            self.last_id = max(self.last_id, f.id)

    def note_reply(self, f):
        """The worker answers in order: its reply settles the oldest request."""
        with self.lock:
            req = self.outstanding.popleft() if self.outstanding else None
            if req is not None:
                self.answered.append(req)
        return req

    def pick_id(self, ident, trigger, rng):
        with self.lock:
            oldest = self.outstanding[0] if self.outstanding else None
            if ident == "oldest" and oldest is not None:
                return oldest.id, oldest
            if ident == "answered" and self.answered:
                req = rng.choice(list(self.answered))
                return req.id, req
            if ident == "unsent":
                return self.last_id + 1 + rng.randrange(0, 3), None
            if ident == "random":
                return rng.randrange(0, 1 << 32), None
        return trigger.id, trigger.request or oldest


class HostileProxy:
    """Listens on a loopback port; every connection to it is dialled on to
    the worker at self.target and damaged by the armed schedule. `victim`:
    the worker process (kill/stop actions); both may be changed between
    schedules (retarget)."""

    def __init__(self, target, victim=None, rules=(), joining=False):
        self.target, self.victim = target, Victim(victim) if victim is not None else None
        self.joining = joining  # the worker connects (--join), the proxy dials the coordinator
        self.lock = threading.Lock()
        self.idle = threading.Condition(self.lock)
        self.acting = 0  # frames whose rules are being applied
        self.rules = list(rules)
        self.events = []  # what the proxy did, in order
        self.links = []
        self.counts = collections.Counter()  # (side, type) -> frames seen since armed
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(16)
        self.addr = "127.0.0.1:%d" % self.sock.getsockname()[1]
        self.t0 = time.monotonic()
        threading.Thread(target=self.accept, daemon=True).start()

    # -- control

    def arm(self, rules):
        """A new schedule: counting starts again from here, once the
        actions under way have ended (none of the last schedule's can land
        in this one)."""
        with self.idle:
            self.idle.wait_for(lambda: self.acting == 0, timeout=30)
            self.rules = list(rules)
            self.counts.clear()
            self.events = []

    def retarget(self, target, victim):
        with self.lock:
            self.target, self.victim = target, Victim(victim)

    def cut_all(self):
        for link in list(self.links):
            link.close()

    def close(self):
        self.sock.close()
        self.cut_all()

    def log(self, text):
        with self.lock:
            self.events.append(f"{time.monotonic() - self.t0:8.3f} {text}")

    def fired(self):
        return [r for r in self.rules if r.fired.is_set()]

    # -- plumbing

    def accept(self):
        n = 0
        while True:
            try:
                a, _ = self.sock.accept()
            except OSError:
                return
            host, port = self.target.rsplit(":", 1)
            try:
                b = socket.create_connection((host, int(port)), timeout=2)
                b.settimeout(None)
            except OSError:
                a.close()  # the worker is gone: the coordinator dials again
                continue
            for s in (a, b):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            n += 1
            link = Link(self, b, a, n) if self.joining else Link(self, a, b, n)
            link.unanswered_start = self.joining
            link.peer = "%s:%d" % b.getsockname() if self.joining else self.addr
            self.links = [k for k in self.links if not k.closed] + [link]
            threading.Thread(target=self.pump_requests, args=(link,), daemon=True).start()
            threading.Thread(target=self.pump_replies, args=(link,), daemon=True).start()

    def due(self, side, f):
        """The rules that fire on f, which is counted."""
        out = []
        with self.lock:
            self.counts[side, f.type] += 1
            for r in self.rules:
                if r.fired.is_set() or not r.matches(side, f):
                    continue
                r.seen += 1
                if r.seen == r.nth:
                    out.append(r)
            self.acting += bool(out)
        return out

    def acted(self):
        with self.idle:
            self.acting -= 1
            self.idle.notify_all()

    def pump_requests(self, link):
        """Coordinator -> worker: bytes forwarded as they come; frames read
        on the way for the requests' FIFO and the request-side rules."""
        reader = FrameReader()
        try:
            while True:
                data = link.coord.recv(1 << 16)
                if not data:
                    break
                reader.feed(data)
                frames = reader.frames()
                for f in frames:
                    link.note_request(f)
                    rules = self.due("request", f)
                    try:
                        for r in rules:
                            self.act_on_request(link, r, f)
                    finally:
                        if rules:
                            self.acted()
                link.worker.sendall(data)
        except (OSError, ProtocolViolation):
            pass
        link.close()

    def act_on_request(self, link, r, f):
        self.log(f"link {link.number}: {r} on {f}")
        p = r.params
        if r.action in ("kill", "stop", "signal"):
            self.signal(r)
        elif r.action == "cut":
            link.close()
        elif r.action == "call":
            p["fn"](link, f)
        r.fired.set()
        r.done.set()

    def signal(self, r):
        p = r.params
        target = Victim(p["target"]) if "target" in p else self.victim
        sig = {"kill": signal.SIGKILL, "stop": signal.SIGSTOP}.get(r.action, p.get("sig"))
        target.send(sig)
        resume = p.get("seconds", p.get("resume_after"))
        if sig == signal.SIGSTOP and resume:
            t = threading.Timer(resume, target.send, args=(signal.SIGCONT,))
            t.daemon = True
            t.start()

    def pump_replies(self, link):
        """Worker -> coordinator: whole frames, each through the rules."""
        reader = FrameReader()
        held = None  # a reply held for a reorder, and until when
        try:
            while not link.closed:
                wait = None if held is None else max(0.0, held[1] - time.monotonic())
                ready, _, _ = select.select([link.worker], [], [], wait)
                if not ready:  # no next reply to swap with: the held one goes alone
                    self.log(f"link {link.number}: nothing to reorder {held[0]} with; sent alone")
                    link.coord.sendall(held[0].raw)
                    held = None
                    continue
                data = link.worker.recv(1 << 16)
                if not data:
                    break
                reader.feed(data)
                for f in reader.frames():
                    f.request = link.note_reply(f)
                    if held is not None:
                        link.coord.sendall(f.raw + held[0].raw)
                        self.log(f"link {link.number}: sent {f} ahead of {held[0]}")
                        held = None
                        continue
                    rules = self.due("reply", f)
                    if not rules:
                        link.coord.sendall(f.raw)
                        continue
                    try:  # one action a frame: a rule due with another is not applied
                        held = self.act_on_reply(link, rules[0], f)
                    finally:  # also when the coordinator is gone
                        rules[0].done.set()
                        self.acted()
                    if link.closed:
                        return
        except (OSError, ProtocolViolation):
            pass
        link.close()

    def act_on_reply(self, link, r, f):
        """Applies r to reply f; returns (f, until) when f is held for a
        reorder, else None."""
        p, a = r.params, r.action
        self.log(f"link {link.number}: {r} on {f}")
        r.fired.set()
        send = link.coord.sendall
        if a == "pass":
            send(f.raw)
        elif a == "dup":
            send(f.raw + f.raw)
        elif a == "reorder":
            return f, time.monotonic() + p.get("hold_max", 0.25)
        elif a == "delay":
            time.sleep(p.get("ms", 200) / 1000)
            send(f.raw)
        elif a == "drop":
            if p.get("cut_after") is not None:
                t = threading.Timer(p["cut_after"], link.close)
                t.daemon = True
                t.start()
        elif a == "truncate":
            if p.get("how", "payload") == "payload":
                keep = p.get("keep", len(f.payload) // 2)
                send(frame_bytes(f.type, f.id, f.payload[:keep]))
            else:
                send(f.raw[:max(1, len(f.raw) // 2)])
                if p.get("then") == "kill":
                    self.victim.send(signal.SIGKILL)
                    time.sleep(p.get("linger", 0.05))
                link.close()
        elif a == "forge":
            forged = p["forge"].build(link, f)
            r.note = f"{p['forge']} id {struct.unpack_from('<I', forged, 8)[0]:#x}"
            place = p.get("place", "before")
            if place == "before":
                send(forged)
                if p.get("hold"):
                    time.sleep(p["hold"])
                send(f.raw)
            elif place == "after":
                send(f.raw + forged)
            else:  # instead
                send(forged)
        elif a == "cut":
            link.close()
        elif a in ("kill", "stop", "signal"):
            if p.get("forward", True):
                send(f.raw)
            self.signal(r)
        elif a == "call":
            p["fn"](link, f)
            send(f.raw)
        else:
            raise ValueError(f"unknown action {a!r}")
        return None


# ---- daemons and jobs -------------------------------------------------------

def dropped_lines(log, addr=None):
    """The coordinator's `worker N (PEER) dropped: REASON` lines (of the
    worker at addr, if given), as (id, peer, reason) tuples."""
    import re
    out = []
    for m in re.finditer(r"worker (\d+) \(([^\s)]+)\) dropped: (.*)", log):
        if addr is None or m.group(2) == addr:
            out.append((int(m.group(1)), m.group(2), m.group(3)))
    return out


def ready_lines(log):
    """The `worker N (PEER, ...) ready` lines as (id, peer) tuples."""
    import re
    return [(int(m.group(1)), m.group(2)) for m in re.finditer(r"worker (\d+) \(([^,\s)]+), [^)\n]*\) ready", log)]
