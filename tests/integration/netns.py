"""Network namespaces for the partition tests and the soak: a coordinator's
namespace and one namespace per worker slot, each slot joined to the
coordinator's by its own veth pair and subnet, so each worker's traffic
crosses an interface of its own that a rule can cut.

    slot i:  coordinator side 10.78.i.1/24  <-- veth -->  10.78.i.2/24 worker side

A partition is an nftables rule that drops what arrives on one end of a
slot's veth (the input hook of the receiving namespace), never what leaves:
a rule on the output hook makes the sender's own send() or connect() fail
at once (EPERM), which a real network never does. Dropping on arrival is a
silent loss: the sender's TCP retransmits and hears nothing, as behind a
dead switch. Only IP is dropped; ARP still answers, so a healed link works
at once.

Needs root, and nft for partitions (deploy/install-deps.sh installs
nftables). bench/netem.py uses it for its one slot's latency. Every
namespace carries the tag given (default: this process's pid), so runs
side by side do not collide; close() removes them all, and their veths
with them."""
import os
import re
import shutil
import subprocess

SUBNET = "10.78"
DIRECTIONS = ("both", "to_worker", "to_coordinator")


def sh(*args, check=True, input=None):
    p = subprocess.run([str(a) for a in args], capture_output=True, text=True, input=input)
    if check and p.returncode != 0:
        raise RuntimeError(f"{' '.join(map(str, args))}: {p.stderr.strip() or 'exit %d' % p.returncode}")
    return p


def missing(partitions=True):
    """Why namespaces (and partitions) cannot be made here (None: they can)."""
    if os.geteuid() != 0:
        return "needs root (network namespaces" + (", nftables)" if partitions else ")")
    for tool, pkg in (("ip", "iproute2"), ("nft", "nftables"))[:2 if partitions else 1]:
        if shutil.which(tool) is None:
            return f"needs {tool} (Debian package {pkg}: deploy/install-deps.sh installs it)"
    return None


class Net:
    """The coordinator's namespace and `slots` worker namespaces."""

    def __init__(self, slots, tag=None):
        self.slots = slots
        self.tag = tag or f"tx{os.getpid() % 100000}"
        self.coord_ns = f"{self.tag}c"
        self.made = []          # namespaces created, for close()
        self.cut = {}           # slot -> direction of its partition

    # ---- names and addresses

    def worker_ns(self, i):
        return f"{self.tag}w{i}"

    def coord_dev(self, i):
        """The slot's veth end in the coordinator's namespace."""
        return f"{self.tag}c{i}"

    def worker_dev(self, i):
        return f"{self.tag}w{i}"

    def coord_ip(self, i):
        """The coordinator's address as slot i sees it (for --join)."""
        return f"{SUBNET}.{i}.1"

    def worker_ip(self, i):
        return f"{SUBNET}.{i}.2"

    def cmd(self, ns, *argv):
        """argv run inside namespace ns (`ip netns exec` execs it: the pid
        is the program's own)."""
        return ["ip", "netns", "exec", ns, *[str(a) for a in argv]]

    def in_coord(self, *argv):
        return self.cmd(self.coord_ns, *argv)

    def in_worker(self, i, *argv):
        return self.cmd(self.worker_ns(i), *argv)

    # ---- making and removing

    def create(self, partitions=True):
        """Makes the namespaces; partitions=False: nft is not needed (no
        partition() calls will follow)."""
        why = missing(partitions)
        if why:
            raise RuntimeError(why)
        self._add_ns(self.coord_ns)
        for i in range(self.slots):
            self.add_slot(i)
        return self

    def _add_ns(self, ns):
        sh("ip", "netns", "add", ns)
        self.made.append(ns)
        sh("ip", "-n", ns, "link", "set", "lo", "up")

    def add_slot(self, i):
        """Slot i's namespace and veth (again, after vanish())."""
        ns, cdev, wdev = self.worker_ns(i), self.coord_dev(i), self.worker_dev(i)
        self._add_ns(ns)
        sh("ip", "link", "add", cdev, "netns", self.coord_ns, "type", "veth", "peer", "name", wdev, "netns", ns)
        for where, dev, ip in ((self.coord_ns, cdev, self.coord_ip(i)), (ns, wdev, self.worker_ip(i))):
            sh("ip", "-n", where, "addr", "add", f"{ip}/24", "dev", dev)
            sh("ip", "-n", where, "link", "set", dev, "up")

    def vanish(self, i):
        """Slot i's host loses power: its veth is deleted (both ends at
        once, so the coordinator's route to it goes), then its namespace.
        Cut the slot first, and anything its sockets say as they die (a
        killed worker's FIN or RST, an answer to a retransmission) is lost
        on the way: the coordinator hears nothing. Healing first would let
        the worker side's kernel reset the coordinator's connection."""
        sh("ip", "-n", self.coord_ns, "link", "del", self.coord_dev(i))
        ns = self.worker_ns(i)
        sh("ip", "netns", "del", ns)
        self.made.remove(ns)
        if self.cut.pop(i, None) is not None:
            sh("ip", "netns", "exec", self.coord_ns, "nft", "delete", "table", "inet", self._table(i), check=False)

    def close(self):
        for ns in reversed(self.made):
            sh("ip", "netns", "del", ns, check=False)
        self.made = []
        self.cut = {}

    # ---- partitions

    def _table(self, i):
        return f"texsyn_cut{i}"

    def _drop_arriving(self, ns, dev, table):
        sh("ip", "netns", "exec", ns, "nft", "-f", "-", input=(
            f"table inet {table} {{\n"
            f"  chain input {{ type filter hook input priority -300; policy accept; "
            f"iifname \"{dev}\" meta nfproto ipv4 counter drop; }}\n"
            f"}}\n"))

    def partition(self, i, direction="both"):
        """Cuts slot i: both ways, or only what travels to_worker
        (coordinator -> worker) or to_coordinator (worker -> coordinator).
        A second call replaces the first."""
        if direction not in DIRECTIONS:
            raise ValueError(f"direction {direction!r}: one of {DIRECTIONS}")
        self.heal(i)
        if direction in ("both", "to_worker"):
            self._drop_arriving(self.worker_ns(i), self.worker_dev(i), self._table(i))
        if direction in ("both", "to_coordinator"):
            self._drop_arriving(self.coord_ns, self.coord_dev(i), self._table(i))
        self.cut[i] = direction

    def heal(self, i):
        """Removes slot i's rules (none: nothing to do)."""
        if self.cut.pop(i, None) is None:
            return
        for ns in (self.worker_ns(i), self.coord_ns):
            if ns in self.made:
                sh("ip", "netns", "exec", ns, "nft", "delete", "table", "inet", self._table(i), check=False)

    def dropped(self, i):
        """Packets slot i's rules have dropped, by direction ({} when it is
        not cut): proof that the partition cut real traffic."""
        out = {}
        for name, ns in (("to_worker", self.worker_ns(i)), ("to_coordinator", self.coord_ns)):
            p = sh("ip", "netns", "exec", ns, "nft", "list", "table", "inet", self._table(i), check=False)
            m = re.search(r"counter packets (\d+)", p.stdout) if p.returncode == 0 else None
            if m:
                out[name] = int(m.group(1))
        return out
