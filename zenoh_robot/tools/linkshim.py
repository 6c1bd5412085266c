"""A UDP tunnel in front of Zenoh's UDP link that sends each datagram K times, K following the measured loss.

Zenoh 1.10 opens a unicast session with four datagrams that are never re-sent within a try, so a
try succeeds with (1 - loss)^4: a session from a 90 % lossy start takes about an hour
(docs/results/transports.md). Declarations that are lost on a single UDP link are never repeated
either. This shim (the wfb-ng / UDPspeeder pattern) repeats every datagram on the lossy hop so that
the handshake and the declarations cross, then falls back to one or two copies once the other end
reports a good link.

Two ends, plain sockets, no Zenoh:

- drone end: listens on a local UDP port that the companion's Zenoh connects to
  (``udp/127.0.0.1:P``). Each local source address (Zenoh opens a new socket per try) is a flow with
  a random id; its datagrams go to the ground end across the lossy link.
- ground end: listens on the lossy link. Each (remote address, flow id) gets its own socket to the
  router's/GCS's UDP endpoint, so Zenoh sees one peer per flow, as it would without the shim.

Each datagram on the lossy hop carries a 17-byte header: magic, version, copies, flow id, seq (the
datagram's number: copies share it, the receiver forwards the first and drops the rest), pseq (a
number per physical packet: its gaps are the per-packet loss the receiver measures) and feedback
(the sender's measurement of the other direction's loss, which sets the other end's K).

Everything is bounded: flows, the dedup window, the copy queue, the bytes per second of copies; every
drop is counted, garbage is counted and dropped, logs are rate-limited.
"""
from __future__ import annotations

import heapq
import logging
import math
import secrets
import selectors
import socket
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from zenoh_robot.ratelimit import RateLimitedLog

log = logging.getLogger("zenoh_robot.linkshim")

MAGIC = b"ZS"
VERSION = 1
HEADER = struct.Struct("!2sBBIIIB")     # magic, version, copies, flow, seq, pseq, feedback
FB_UNKNOWN = 255                         # feedback byte: no measurement yet
FB_SCALE = 250                           # feedback byte = loss * 250
MAX_DATAGRAM = 65535
DEDUP_WINDOW = 1024                      # seqs remembered per flow: copies arrive within ~100 ms


@dataclass(frozen=True)
class ShimConfig:
    k_warm: int = 32            # copies while the flow is young, quiet or has no loss report (handshake)
    k_small_max: int = 16       # copies of a small datagram once the loss is measured
    k_big_max: int = 2          # copies of a big one (streams: their own repeats and FEC handle loss)
    big_warm_max: int = 4       # a big datagram's copies during warm-up
    small_bytes: int = 600      # handshake, declarations, keep-alives, setpoints are below this
    miss_small: float = 1e-3    # target chance that every copy of a small datagram is lost
    miss_big: float = 0.1
    warm_s: float = 5.0         # a flow's first seconds: handshake and declarations
    warm_datagrams: int = 100   # a flow's first datagrams get k_warm whatever their size: declarations are
    # batched up to the batch size at start-up, and one lost batch silences a stream for good
    quiet_s: float = 1.0        # nothing from the other end for this long: the session may be re-forming
    spacing_s: float = 0.003    # between copies: spreads them over a burst of loss
    max_flows: int = 64
    idle_s: float = 60.0        # a flow silent both ways this long is forgotten
    max_pending: int = 20000    # copies waiting for their send time
    budget_Bps: float = 4e6     # bytes/s of extra copies (first copies are never held back)
    log_every_s: float = 5.0
    # Zenoh drops a frame older than one it has (per channel): a later datagram must not overtake an earlier
    # one whose first copies were lost, or the reliable channel (declarations) loses it for good. Hold the
    # later ones until the gap fills from a copy, at most spacing * K + hold_margin_s (capped).
    max_hold_s: float = 0.06
    hold_margin_s: float = 0.005
    max_held: int = 256         # datagrams held per flow; beyond, the oldest gap is given up

    def __post_init__(self) -> None:
        if not 1 <= self.k_big_max <= self.k_small_max <= 255 or not 1 <= self.k_warm <= 255:
            raise ValueError("copies must satisfy 1 <= k_big_max <= k_small_max <= 255 and 1 <= k_warm <= 255")
        if self.max_flows < 1 or self.max_pending < 1 or self.budget_Bps < 0 or self.spacing_s < 0:
            raise ValueError("max_flows, max_pending >= 1; budget and spacing >= 0")


def copies(cfg: ShimConfig, size: int, loss: float | None, warm: bool) -> int:
    """How many times to send a datagram of ``size`` bytes given the other end's loss report.

    With independent loss p, K copies all vanish with p^K: K = ceil(ln(miss) / ln(p)). Until the
    loss is known (and while the flow is young or quiet) the handshake has to cross: send k_warm."""
    small = size <= cfg.small_bytes
    if warm or loss is None:
        return cfg.k_warm if small else min(cfg.k_warm, cfg.big_warm_max)
    cap, miss = (cfg.k_small_max, cfg.miss_small) if small else (cfg.k_big_max, cfg.miss_big)
    if loss <= 0.0:
        return 1
    if loss >= 1.0:
        return cap
    return max(1, min(cap, math.ceil(math.log(miss) / math.log(loss))))


@dataclass(frozen=True)
class Header:
    copies: int
    flow: int
    seq: int
    pseq: int
    feedback: float | None      # the sender's measured loss of the packets we send it

    def pack(self) -> bytes:
        fb = FB_UNKNOWN if self.feedback is None else max(0, min(FB_SCALE, round(self.feedback * FB_SCALE)))
        return HEADER.pack(MAGIC, VERSION, self.copies, self.flow, self.seq, self.pseq, fb)


def parse(packet: bytes) -> tuple[Header, bytes] | None:
    """The header and payload, or None for anything that is not a well-formed shim packet."""
    if len(packet) < HEADER.size:
        return None
    magic, version, k, flow, seq, pseq, fb = HEADER.unpack_from(packet)
    if magic != MAGIC or version != VERSION or k == 0 or fb > FB_SCALE and fb != FB_UNKNOWN:
        return None
    return Header(k, flow, seq, pseq, None if fb == FB_UNKNOWN else fb / FB_SCALE), packet[HEADER.size:]


class Dedup:
    """Seqs seen in the last ``window`` numbers (a bitmask): copies and stale packets are refused."""

    def __init__(self, window: int = DEDUP_WINDOW) -> None:
        self.window = window
        self.hi = -1
        self.mask = 0         # bit i: seq hi - i seen

    def fresh(self, seq: int) -> bool:
        if self.hi < 0 or seq > self.hi:
            shift = seq - self.hi if self.hi >= 0 else self.window
            self.mask = ((self.mask << shift) | 1) & ((1 << self.window) - 1) if shift < self.window else 1
            self.hi = seq
            return True
        back = self.hi - seq
        if back >= self.window or self.mask >> back & 1:
            return False
        self.mask |= 1 << back
        return True


class LossMeter:
    """Per-packet loss from pseq gaps over windows of ``every`` expected packets (or 1 s), smoothed."""

    def __init__(self, every: int = 64, alpha: float = 0.5) -> None:
        self.every, self.alpha = every, alpha
        self.first = -1
        self.hi = -1
        self.count = 0
        self.t0 = 0.0
        self.loss: float | None = None

    def seen(self, pseq: int, now: float) -> None:
        if self.first < 0:
            self.first, self.hi, self.count, self.t0 = pseq, pseq, 1, now
            return
        if pseq < self.first or pseq > self.hi + 100_000:   # a restart or garbage: start a new window
            self.first, self.hi, self.count, self.t0 = pseq, pseq, 1, now
            return
        self.hi = max(self.hi, pseq)
        self.count += 1
        expected = self.hi - self.first + 1
        if expected >= self.every or (now - self.t0 >= 1.0 and expected >= 8):
            sample = max(0.0, min(1.0, 1.0 - self.count / expected))
            self.loss = sample if self.loss is None else self.alpha * sample + (1 - self.alpha) * self.loss
            self.first, self.count, self.t0 = self.hi + 1, 0, now


@dataclass
class Flow:
    fid: int
    wire_addr: tuple[str, int]                  # the other shim
    local_addr: tuple[str, int] | None          # drone end: Zenoh's socket; ground end: unused
    sock: socket.socket | None = None           # ground end: this flow's socket to the target
    created: float = 0.0
    last_rx: float = 0.0                        # last packet from the other shim
    last_active: float = 0.0
    seq: int = 0
    pseq: int = 0
    dedup: Dedup = field(default_factory=Dedup)
    meter: LossMeter = field(default_factory=LossMeter)
    peer_loss: float | None = None              # the other end's measurement of what we send
    next_seq: int = -1                          # the next seq to forward in order (-1: none yet)
    held: dict[int, bytes] = field(default_factory=dict)
    hold_until: float = 0.0


class LinkShim:
    """One end of the tunnel. ``role`` "drone": ``listen`` is local (Zenoh connects to it), datagrams go
    to ``peer`` (the ground end). ``role`` "ground": ``listen`` is on the lossy link, datagrams go to
    ``target`` (the router's UDP endpoint), one socket per flow."""

    def __init__(self, role: str, listen: tuple[str, int], *, peer: tuple[str, int] | None = None,
                 target: tuple[str, int] | None = None, cfg: ShimConfig | None = None,
                 clock: Callable[[], float] = time.monotonic) -> None:
        if role not in ("drone", "ground"):
            raise ValueError(f"role must be drone or ground, got {role!r}")
        if role == "drone" and peer is None or role == "ground" and target is None:
            raise ValueError("the drone end needs peer (the ground end), the ground end needs target")
        self.role, self.peer, self.target = role, peer, target
        self.cfg = cfg or ShimConfig()
        self.clock = clock
        self.sel = selectors.DefaultSelector()
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
        self.sock.bind(listen)
        self.sock.setblocking(False)
        self.address: tuple[str, int] = self.sock.getsockname()
        # Drone end: the lossy hop leaves from a socket of its own, so the local port only faces Zenoh.
        self.wire = self.sock if role == "ground" else self._new_socket()
        self.sel.register(self.sock, selectors.EVENT_READ, self._on_listen)
        if self.wire is not self.sock:
            self.sel.register(self.wire, selectors.EVENT_READ, self._on_wire)
        self.flows: dict[int, Flow] = {}                          # drone end: by flow id
        self.by_local: dict[tuple[str, int], int] = {}            # drone end: Zenoh's address -> flow id
        self.by_remote: dict[tuple[tuple[str, int], int], Flow] = {}   # ground end: (shim addr, flow id)
        # due, order, flow id, copies, seq, payload, to: a copy's header is built when it leaves (own pseq,
        # latest feedback)
        self.pending: list[tuple[float, int, int, int, int, bytes, tuple[str, int]]] = []
        self._order = 0
        self.tokens = self.cfg.budget_Bps
        self._refill_t = clock()
        self.counters: dict[str, int] = {k: 0 for k in (
            "rx_local", "rx_wire", "forwarded", "duplicates", "stale", "garbage", "unknown_flow", "tx_first",
            "tx_copies", "tx_bytes", "copies_over_budget", "copies_queue_full", "flows_opened",
            "flows_evicted", "send_errors", "held", "gaps_skipped", "late")}
        self.rlog = RateLimitedLog(log, burst=1, interval=self.cfg.log_every_s)
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    # ---- running
    def start(self) -> "LinkShim":
        self._thread = threading.Thread(target=self.run, name=f"linkshim-{self.role}", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for f in list(self.flows.values()) + list(self.by_remote.values()):
            if f.sock is not None:
                f.sock.close()
        if self.wire is not self.sock:
            self.wire.close()
        self.sock.close()
        self.sel.close()

    def run(self) -> None:
        last_sweep = self.clock()
        while not self._stop.is_set():
            now = self.clock()
            due = [self.pending[0][0]] if self.pending else []
            due += [f.hold_until for f in self._all_flows() if f.held]
            timeout = max(0.0, min([0.2, *(d - now for d in due)]))
            for key, _ in self.sel.select(timeout):
                key.data(key.fileobj)
            self._flush_due(self.clock())
            self._expire_holds(self.clock())
            if self.clock() - last_sweep > 1.0:
                last_sweep = self.clock()
                self._evict_idle(last_sweep)

    def stats(self) -> dict[str, object]:
        flows = list(self.flows.values()) if self.role == "drone" else list(self.by_remote.values())
        return {"role": self.role, **self.counters, "flows": len(flows), "pending": len(self.pending),
                "loss_in": [None if f.meter.loss is None else round(f.meter.loss, 3) for f in flows],
                "loss_out": [None if f.peer_loss is None else round(f.peer_loss, 3) for f in flows]}

    # ---- receive paths
    def _drain(self, sock: socket.socket) -> list[tuple[bytes, tuple[str, int]]]:
        out = []
        for _ in range(256):            # bounded: the other socket and the copy queue get their turn
            try:
                data, addr = sock.recvfrom(MAX_DATAGRAM)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:       # ICMP unreachable surfaces here on Linux: the target is not up yet
                self.counters["send_errors"] += 1
                self.rlog.warning("recv", "linkshim %s: receive error: %s", self.role, exc)
                continue
            out.append((data, addr))
        return out

    def _on_listen(self, sock: socket.socket) -> None:
        if self.role == "ground":
            self._on_wire(sock)
            return
        now = self.clock()
        for data, addr in self._drain(sock):
            self.counters["rx_local"] += 1
            flow = self._drone_flow(addr, now)
            if flow is not None:
                self._send(flow, data, now)

    def _on_wire(self, sock: socket.socket) -> None:
        now = self.clock()
        for packet, addr in self._drain(sock):
            self.counters["rx_wire"] += 1
            parsed = parse(packet)
            if parsed is None:
                self.counters["garbage"] += 1
                self.rlog.warning("garbage", "linkshim %s: dropped a malformed datagram from %s", self.role, addr)
                continue
            head, payload = parsed
            flow = self._wire_flow(head.flow, addr, now)
            if flow is None:
                continue
            flow.last_rx = flow.last_active = now
            flow.meter.seen(head.pseq, now)
            if head.feedback is not None:
                flow.peer_loss = head.feedback
            if not flow.dedup.fresh(head.seq):
                self.counters["duplicates" if flow.dedup.hi - head.seq < flow.dedup.window else "stale"] += 1
                continue
            self._in_order(flow, head, payload, now)

    def _in_order(self, flow: Flow, head: Header, payload: bytes, now: float) -> None:
        seq = head.seq
        if flow.next_seq < 0 or seq == flow.next_seq:
            self._forward(flow, payload)
            flow.next_seq = (seq + 1) & 0xFFFFFFFF
            self._release(flow)
        elif seq < flow.next_seq:
            # Its gap was given up: forward anyway (it may be in order on its own Zenoh channel).
            self.counters["late"] += 1
            self._forward(flow, payload)
        else:
            if not flow.held:
                flow.hold_until = now + min(self.cfg.max_hold_s, self.cfg.spacing_s * head.copies
                                            + self.cfg.hold_margin_s)
            flow.held[seq] = payload
            self.counters["held"] += 1
            if len(flow.held) > self.cfg.max_held:
                self._skip_gap(flow)

    def _release(self, flow: Flow) -> None:
        while flow.next_seq in flow.held:
            self._forward(flow, flow.held.pop(flow.next_seq))
            flow.next_seq = (flow.next_seq + 1) & 0xFFFFFFFF

    def _skip_gap(self, flow: Flow) -> None:
        """The missing datagram is not coming: forward from the oldest held one on."""
        first = min(flow.held)
        self.counters["gaps_skipped"] += 1
        flow.next_seq = first
        self._release(flow)

    def _expire_holds(self, now: float) -> None:
        for flow in self._all_flows():
            if flow.held and now >= flow.hold_until:
                self._skip_gap(flow)
                if flow.held:       # another gap behind: it gets its own (short) wait
                    flow.hold_until = now + self.cfg.hold_margin_s

    def _forward(self, flow: Flow, payload: bytes) -> None:
        self.counters["forwarded"] += 1
        try:
            if self.role == "drone":
                assert flow.local_addr is not None
                self.sock.sendto(payload, flow.local_addr)
            else:
                assert flow.sock is not None
                flow.sock.send(payload)
        except OSError as exc:
            self.counters["send_errors"] += 1
            self.rlog.warning("fwd", "linkshim %s: forward failed: %s", self.role, exc)

    def _on_target(self, sock: socket.socket) -> None:
        """Ground end: the router answers a flow."""
        now = self.clock()
        flow = next((f for f in self.by_remote.values() if f.sock is sock), None)
        for data, _ in self._drain(sock):
            self.counters["rx_local"] += 1
            if flow is not None:
                self._send(flow, data, now)

    # ---- flows
    def _drone_flow(self, addr: tuple[str, int], now: float) -> Flow | None:
        fid = self.by_local.get(addr)
        if fid is not None:
            flow = self.flows[fid]
            flow.last_active = now
            return flow
        if len(self.flows) >= self.cfg.max_flows:
            self._evict_oldest()
        fid = secrets.randbits(32)
        while fid in self.flows:
            fid = secrets.randbits(32)
        assert self.peer is not None
        flow = Flow(fid, self.peer, addr, created=now, last_active=now)
        self.flows[fid], self.by_local[addr] = flow, fid
        self.counters["flows_opened"] += 1
        return flow

    def _wire_flow(self, fid: int, addr: tuple[str, int], now: float) -> Flow | None:
        if self.role == "drone":
            flow = self.flows.get(fid)
            if flow is None or addr != self.peer:
                self.counters["unknown_flow"] += 1
                return None
            return flow
        key = (addr, fid)
        flow = self.by_remote.get(key)
        if flow is not None:
            return flow
        if len(self.by_remote) >= self.cfg.max_flows:
            self._evict_oldest()
        assert self.target is not None
        s = self._new_socket()
        try:
            s.connect(self.target)
        except OSError as exc:
            s.close()
            self.counters["send_errors"] += 1
            self.rlog.warning("connect", "linkshim ground: cannot reach target %s: %s", self.target, exc)
            return None
        flow = Flow(fid, addr, None, sock=s, created=now, last_active=now)
        self.by_remote[key] = flow
        self.sel.register(s, selectors.EVENT_READ, self._on_target)
        self.counters["flows_opened"] += 1
        return flow

    def _new_socket(self) -> socket.socket:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 << 20)
        s.bind(("0.0.0.0", 0))
        s.setblocking(False)
        return s

    def _all_flows(self) -> list[Flow]:
        return list(self.flows.values()) if self.role == "drone" else list(self.by_remote.values())

    def _drop_flow(self, flow: Flow) -> None:
        if self.role == "drone":
            self.flows.pop(flow.fid, None)
            if flow.local_addr is not None:
                self.by_local.pop(flow.local_addr, None)
        else:
            self.by_remote.pop((flow.wire_addr, flow.fid), None)
            if flow.sock is not None:
                self.sel.unregister(flow.sock)
                flow.sock.close()
        self.counters["flows_evicted"] += 1

    def _evict_oldest(self) -> None:
        flows = self._all_flows()
        if flows:
            self._drop_flow(min(flows, key=lambda f: f.last_active))

    def _evict_idle(self, now: float) -> None:
        for f in self._all_flows():
            if now - f.last_active > self.cfg.idle_s:
                self._drop_flow(f)

    # ---- send path
    def _send(self, flow: Flow, payload: bytes, now: float) -> None:
        if len(payload) > MAX_DATAGRAM - HEADER.size - 28:
            self.counters["garbage"] += 1
            return
        warm = now - flow.created < self.cfg.warm_s or now - flow.last_rx > self.cfg.quiet_s
        k = self.cfg.k_warm if flow.seq < self.cfg.warm_datagrams else copies(self.cfg, len(payload),
                                                                              flow.peer_loss, warm)
        seq = flow.seq
        flow.seq = (flow.seq + 1) & 0xFFFFFFFF
        self._emit(flow, k, seq, payload)
        self.counters["tx_first"] += 1
        self._refill(now)
        size = HEADER.size + len(payload)
        for i in range(1, k):
            if self.tokens < size:
                self.counters["copies_over_budget"] += k - i
                break
            if len(self.pending) >= self.cfg.max_pending:
                self.counters["copies_queue_full"] += k - i
                break
            self.tokens -= size
            self._order += 1
            heapq.heappush(self.pending, (now + i * self.cfg.spacing_s, self._order, flow.fid, k, seq, payload,
                                          flow.wire_addr))

    def _emit(self, flow: Flow, k: int, seq: int, payload: bytes) -> None:
        head = Header(k, flow.fid, seq, flow.pseq, flow.meter.loss)
        flow.pseq = (flow.pseq + 1) & 0xFFFFFFFF
        packet = head.pack() + payload
        try:
            self.wire.sendto(packet, flow.wire_addr)
            self.counters["tx_bytes"] += len(packet)
        except OSError as exc:          # a full socket buffer, or the route is gone: counted, never fatal
            self.counters["send_errors"] += 1
            self.rlog.warning("send", "linkshim %s: send failed: %s", self.role, exc)

    def _flush_due(self, now: float) -> None:
        while self.pending and self.pending[0][0] <= now:
            _, _, fid, k, seq, payload, wire_addr = heapq.heappop(self.pending)
            flow = self._flow_by_id(fid, wire_addr)
            if flow is None:
                continue
            self._emit(flow, k, seq, payload)
            self.counters["tx_copies"] += 1

    def _flow_by_id(self, fid: int, wire_addr: tuple[str, int]) -> Flow | None:
        return self.flows.get(fid) if self.role == "drone" else self.by_remote.get((wire_addr, fid))

    def _refill(self, now: float) -> None:
        self.tokens = min(self.cfg.budget_Bps, self.tokens + (now - self._refill_t) * self.cfg.budget_Bps)
        self._refill_t = now


def parse_addr(text: str) -> tuple[str, int]:
    """``host:port`` (``udp/`` prefix allowed, as in Zenoh endpoints)."""
    text = text.removeprefix("udp/")
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"expected host:port, got {text!r}")
    return host, int(port)
