"""Loss feedback: each node measures the packet loss it sees and tells its peers.

A publisher cannot see its own losses; its receivers can. A :class:`LossMonitor` per node
sends a tiny best-effort probe (``LinkProbe``, ~100 bytes) every ``period_s`` on its role's
key (Keys, below); each probe carries a sequence number, and the loss the sender measures on
the probes of each peer it hears. So every node knows (a) the loss on its incoming
direction, from the gaps in its peers' probes, and (b) the loss its peers see from it,
from their reports. :meth:`LossMonitor.outgoing_loss` is the worst of both over the peers
heard recently (loss is usually symmetric, and (a) needs no round trip, so it answers a
sudden burst in about one short window). Adapters (:meth:`LossMonitor.adapt`) are called
with it at every probe: e.g. ``monitor.adapt(lambda p: apply_repeat_plan(setpoint_pub, p))``
or ``monitor.adapt(image_pub.set_loss)``. A probe names its sender's namespace (``origin``, a drone's
id), so a GCS can size each drone's copies for that drone's link: ``outgoing_loss(origin)`` and
``burst(origin)`` (one drone in a fade no longer raises every drone's copies).

Estimates: probes that arrived in the last ``window_s`` (and ``long_window_s``) over those
the peer's period says were sent; the larger of the two, so a rise is seen within the short
window and a fall only once the long window agrees. Bounded: at most ``max_peers`` peers
(least recently heard forgotten), ``max_peers`` reports per probe, a peer silent for
``forget_s`` is dropped (a drone that left must not hold the link at "90 %" forever).

Bursts: Wi-Fi loss comes in fades (100 ms to seconds), and copies sized from the mean as if
drops were independent leave a fade with no packet for longer than a deadline. Each peer's probe
sequence numbers give the runs of consecutive losses; :meth:`LossMonitor.burst` reports, over the
long window, their mean and longest length and the loss that follows a loss (1 - runs / lost: for
independent loss it equals the mean, in fades it is near the fade's own loss), and whether that is
more than chance allows for independent drops (:attr:`BurstEstimate.fading`). The probes measure
the incoming direction only; the outgoing one is taken to fade alike (a radio fade is both ways).
:func:`repeat_plan` sizes copies for the larger of the mean and that conditional loss, and in fades
for the fade's own loss: copies of the newest sample go out at a steady rate while samples flow (a
newer one replaces the older copies), so the rate, not the window, decides whether a packet crosses
a fade in time, and the first packet after a fade carries the newest sample.

Keys: a monitor has a role (:data:`ROLES`: a GCS or a drone) and puts its probes on
``<topic>/<role>`` and hears ``<topic>/<other role>``, so a GCS and a drone never subscribe to the
same key. On a lossless UDP multicast group Zenoh 1.10 bounces the declaration of a subscription two
peers both hold (and put to) back and forth for ever, ~4,700 packets/s each way (eclipse-zenoh/zenoh
PR #2802, docs/lossy-link.md): with one probe key for every node that was the 8-11x bytes of the 0 %
resilient cells, sealed or plain. Two monitors of one role share their key (two GCSs on one group,
or drones of a swarm); they do not put to it.

Cost: O(1) amortised per peer per tick. Each window keeps its own deque of the arrival times
still inside it, trimmed from the left as the window slides (arrivals are stamped under the
lock, so each deque is sorted); its length is the count. A rescan of every arrival twice per
20 Hz tick was ~10 % of a GCS's Python time at three drones (docs/results/gcs_cpu.md).
"""
from __future__ import annotations

import logging
import math
import secrets
import threading
import time
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

from .message import Message, array, message, ros_field
from .qos import QoSProfile, ReliabilityPolicy
from .repeater import REPEAT_INTERVAL_S

log = logging.getLogger("zenoh_robot.feedback")

LINK_TOPIC = "/zr_link"
ROLES = ("gcs", "drone")     # a monitor hears the other role's probes only (see the module doc)
MAX_PEERS = 32
MAX_ORIGIN = 128      # characters of a probe's origin (a namespace)
MAX_LOSS = 0.97
PROBE_QOS = QoSProfile(ReliabilityPolicy.BEST_EFFORT, depth=8)


@message(name="zenoh_robot/LinkProbe")
class LinkProbe(Message):
    # Probes are the link's own bookkeeping: statistics of them would be noise (and a put
    # outside the node's namespace that the secure profile's ACL has to allow).
    __zr_no_statistics__ = True
    id: int = ros_field("uint64", default=0)          # the sending monitor (random per node)
    seq: int = ros_field("uint32", default=0)
    period_ms: int = ros_field("uint16", default=50)  # how often the sender probes
    peers: list[int] = array("uint64", default=None)        # monitors the sender hears ...
    loss: list[float] = array("float32", default=None)      # ... and the loss it measures on each (0..1)
    # The sender's namespace (a drone's id): a GCS sizes each drone's copies for that drone's link alone.
    origin: str = ros_field("string", default="")


MAX_ARRIVALS = 2048   # per window: a peer probing faster than it claims saturates the count, not memory
MAX_RUNS = 1024       # loss runs remembered per peer (the long window's, at most)
MAX_RUN = 100_000     # a longer jump of a probe's seq is a restart of the peer, not a loss run
# Fades are called when the loss after a loss exceeds the mean by this many standard deviations of
# its estimate under independent drops (given ``lost`` losses, runs ~ Binomial(lost, 1 - mean): the
# estimate's deviation is sqrt(mean (1 - mean) / lost)), by FADE_MIN_EXCESS at least, over at least
# FADE_MIN_LOST lost probes: a uniform link's noise must not put its copies at the ceiling.
FADE_SIGMAS = 2.0
FADE_MIN_EXCESS = 0.1
FADE_MIN_LOST = 15
# A fade under way is called sooner, from the silence it makes: a peer unheard for longer than
# independent loss at the window's mean explains (its probes all lost, with chance under FADE_SILENCE_P;
# two probes at least). The first fade after a clean stretch is otherwise met with the clean plan
# (40 packets/s) until a 1 s window has counted it: flown, gaps of 330-540 ms in the first 5 s of loss.
FADE_SILENCE_P = 0.01
# What copies a few ms apart meet inside a fade. Probes 50 ms apart cannot resolve it (the probe after
# a lost one may be past the fade's end: 95 % fades of 300 ms read as ~0.8), so it is assumed: the
# deep fade of a Wi-Fi link, and the bursty harness's bad state (docs/lossy-link.md, "Bursty loss").
FADE_LOSS = 0.95


@dataclass(frozen=True)
class BurstEstimate:
    """Runs of consecutive lost probes over the long window (worst peer); zeros when none was lost."""
    mean_run: float = 0.0         # probes lost in a row, on average
    longest_run: int = 0          # probes lost in a row, at most
    mean_run_s: float = 0.0       # the same in seconds (the peer's probe period)
    longest_run_s: float = 0.0
    loss_after_loss: float = 0.0  # P(a probe is lost | the previous one was): 1 - runs / lost
    lost: int = 0                 # probes lost over the long window
    received: int = 0             # ... and received
    silent_probes: float = 0.0    # probe periods since a peer was last heard (the longest, now)

    @property
    def mean_loss(self) -> float:
        """The probes' loss over the same window (0 when none was expected)."""
        sent = self.lost + self.received
        return self.lost / sent if sent else 0.0

    @property
    def fading(self) -> bool:
        """Losses follow losses more than independent drops at this mean allow (see FADE_SIGMAS), or a
        peer has been silent for longer than they explain (see FADE_SILENCE_P)."""
        mean = self.mean_loss
        if mean < 1.0:
            missed = math.ceil(math.log(FADE_SILENCE_P) / math.log(mean)) if mean > 0.0 else 1
            if self.silent_probes > max(2, missed) + 0.5:   # half a period: the next probe's jitter
                return True
        if self.lost < FADE_MIN_LOST or not 0.0 < mean < 1.0:
            return False
        noise = math.sqrt(mean * (1.0 - mean) / self.lost)
        return self.loss_after_loss - mean > max(FADE_MIN_EXCESS, FADE_SIGMAS * noise)

    def as_dict(self) -> dict[str, float]:
        return {"mean_run": round(self.mean_run, 2), "longest_run": self.longest_run,
                "mean_run_s": round(self.mean_run_s, 3), "longest_run_s": round(self.longest_run_s, 3),
                "loss_after_loss": round(self.loss_after_loss, 3), "lost": self.lost, "received": self.received,
                "mean_loss": round(self.mean_loss, 3), "silent_probes": round(self.silent_probes, 1),
                "fading": float(self.fading)}


@dataclass
class _Peer:
    first_seen: float
    period: float
    last: float = 0.0                         # newest arrival (forgetting a silent peer)
    # Arrival times inside the short and the long window (oldest first), trimmed as they slide.
    short: deque[float] = field(default_factory=lambda: deque(maxlen=MAX_ARRIVALS))
    long: deque[float] = field(default_factory=lambda: deque(maxlen=MAX_ARRIVALS))
    origin: str = ""                          # the peer's namespace, as its probes say
    reported: float = math.nan                # the loss this peer sees on our probes
    reported_at: float = 0.0
    last_seq: int | None = None               # highest probe seq heard (loss runs)
    runs: deque[tuple[float, int]] = field(default_factory=lambda: deque(maxlen=MAX_RUNS))  # (ended at, length)
    # Arrival times of in-order probes (no duplicate, no late one) in the long window: the runs' complement.
    fresh: deque[float] = field(default_factory=lambda: deque(maxlen=MAX_ARRIVALS))

    def sequence(self, seq: int, t: float) -> None:
        """A probe's seq: the gap since the last one is a run of lost probes (late ones are ignored)."""
        if self.last_seq is None:
            self.last_seq = seq
            self.fresh.append(t)
            return
        ahead = (seq - self.last_seq) & 0xFFFFFFFF
        if ahead == 0 or ahead >= 1 << 31:
            return                                # a duplicate or a late probe
        if ahead > MAX_RUN:
            self.runs.clear()                     # the peer restarted its count
            self.fresh.clear()
        elif ahead > 1:
            self.runs.append((t, ahead - 1))
        self.fresh.append(t)
        self.last_seq = seq

    def burst(self, window: float, now: float) -> BurstEstimate:
        edge = now - window
        while self.runs and self.runs[0][0] <= edge:
            self.runs.popleft()
        while self.fresh and self.fresh[0] <= edge:
            self.fresh.popleft()
        if not self.runs:
            return BurstEstimate(received=len(self.fresh))
        lost = sum(n for _, n in self.runs)
        longest = max(n for _, n in self.runs)
        mean = lost / len(self.runs)
        return BurstEstimate(mean, longest, mean * self.period, longest * self.period, 1.0 - len(self.runs) / lost,
                             lost, len(self.fresh))

    def arrive(self, t: float) -> None:
        self.last = t
        self.short.append(t)
        self.long.append(t)


def _count_after(arrivals: deque[float], window: float, cutoff: float, now: float) -> int:
    """Arrivals later than ``cutoff`` (>= now - window); drops those the window has left for good."""
    edge = now - window
    while arrivals and arrivals[0] <= edge:
        arrivals.popleft()
    # A young peer's cutoff is its first arrival (the span since first seen): skip it (and ties).
    skip = 0
    for t in arrivals:
        if t > cutoff:
            break
        skip += 1
    return len(arrivals) - skip


def repeat_plan(loss: float, deadline_s: float, miss: float = 1e-6, margin: float = 0.05,
                min_copies: int = 16, max_copies: int = 64, burst: BurstEstimate | None = None,
                stale_s: float | None = None, period_s: float | None = None) -> tuple[int, float]:
    """(copies, window) for a deadline stream at packet loss ``loss``.

    What the receiver must never see is a sample older than ``stale_s`` (default: the deadline; for
    setpoints PX4's 500 ms). The last packet before a fade may carry a sample already one publish
    period old (``period_s``; default 20 % of the deadline, 10 Hz at 500 ms), so the copies must put a
    packet across every ``gap = stale_s - period_s``: with the newest sample re-sent every ``step`` (a
    newer sample replaces the older one's copies and carries it in its history, so copies form one
    steady stream), all are lost with probability ``p ** (gap / step)``. Pick the step so this is
    below ``miss`` for p = loss + ``margin`` (the estimate is noisy), never slower than ``min_copies``
    over the window (0.8 x the deadline: a sudden burst must be survived while the feedback catches
    up) and never faster than one copy per REPEAT_INTERVAL_S.

    ``burst`` (:meth:`LossMonitor.burst`) sizes for fades. Consecutive copies share a fade, so ``p`` is
    at least the loss that follows a loss (uniform 50 % gives 0.5 both ways; 95 % fades at a 50 %
    mean read ~0.8 on probes 50 ms apart). When the probes show fades (:attr:`BurstEstimate.fading`),
    copies a few ms apart meet the fade's own loss, FADE_LOSS, which those probes cannot resolve:
    flown at 50 % bursty, the ~0.8 reading sent 213 packets/s, and a 95 % fade let none through for
    up to 580 ms (docs/lossy-link.md, "Bursty loss").
    """
    window = 0.8 * deadline_s
    stale = deadline_s if stale_s is None else stale_s
    gap = max(REPEAT_INTERVAL_S, stale - (0.2 * deadline_s if period_s is None else period_s))
    if burst is not None:
        loss = max(loss, burst.loss_after_loss) if math.isfinite(loss) else loss
        if burst.fading:
            loss = max(loss, FADE_LOSS) if math.isfinite(loss) else loss
    p = min(MAX_LOSS, max(0.0, loss if math.isfinite(loss) else MAX_LOSS) + margin)
    needed = math.ceil(math.log(miss) / math.log(p)) if p > 0 else 1
    step = max(REPEAT_INTERVAL_S, min(gap / needed, window / min_copies))
    copies = min(max_copies, max(1, math.ceil(window / step)))
    return copies, min(window, copies * step)


def apply_repeat_plan(publisher: Any, loss: float, burst: BurstEstimate | None = None,
                      period_s: float | None = None) -> None:
    """Set a deadline publisher's copies from the measured loss and its fades (see :func:`repeat_plan`)."""
    copies, window = repeat_plan(loss, publisher.qos.deadline, burst=burst, period_s=period_s)
    publisher.set_repeats(copies, window)


def probe_topics(role: str, topic: str = LINK_TOPIC) -> tuple[str, str]:
    """(where a monitor of ``role`` puts its probes, where it hears its peers'): never the same key for
    two roles, so no two peers of different roles declare one subscription (see the module doc)."""
    if role not in ROLES:
        raise ValueError(f"loss monitor role {role!r}: one of {', '.join(ROLES)}")
    other = ROLES[1 - ROLES.index(role)]
    return f"{topic}/{role}", f"{topic}/{other}"


class LossMonitor:
    def __init__(self, node: Any, role: str, topic: str = LINK_TOPIC, period_s: float = 0.05, window_s: float = 1.0,
                 long_window_s: float = 5.0, forget_s: float = 10.0, max_peers: int = MAX_PEERS) -> None:
        self.role = role
        self.origin = str(getattr(node, "namespace", "") or "")
        self.probe_topic, self.peer_topic = probe_topics(role, topic)
        self.id = secrets.randbits(63)
        self.period_s = period_s
        self.window_s = window_s
        self.long_window_s = long_window_s
        self.forget_s = forget_s
        self.max_peers = max_peers
        self._peers: OrderedDict[int, _Peer] = OrderedDict()
        self._lock = threading.Lock()
        self._adapters: list[Callable[[float], None]] = []
        self._seq = 0
        self.probes_sent = 0
        self.probes_received = 0
        self.bad_probes = 0
        self.adapter_errors = 0
        self._last_log = 0.0
        self._pub = node.create_publisher(LinkProbe, self.probe_topic, PROBE_QOS)
        self._sub = node.create_subscription(LinkProbe, self.peer_topic, self._on_probe, PROBE_QOS)
        self._stop = threading.Event()
        # Own thread, not the node's executor: the probe clock must not stall with the callbacks.
        self._thread = threading.Thread(target=self._run, name="zr-link-monitor", daemon=True)
        self._thread.start()

    def adapt(self, callback: Callable[[float], None]) -> None:
        """Call ``callback(outgoing_loss)`` after every probe once a peer is heard."""
        self._adapters.append(callback)

    # -- receive ---------------------------------------------------------------------
    def _on_probe(self, msg: LinkProbe, info: Any = None) -> None:
        if msg.id == self.id:
            return
        if not (1 <= msg.period_ms <= 10_000 and len(msg.peers) == len(msg.loss) <= MAX_PEERS
                and len(msg.origin) <= MAX_ORIGIN):
            self.bad_probes += 1
            return
        with self._lock:
            now = time.monotonic()   # under the lock: arrivals stay sorted, windows trim from the left
            peer = self._peers.get(msg.id)
            if peer is None:
                peer = self._peers[msg.id] = _Peer(now, msg.period_ms / 1000)
                while len(self._peers) > self.max_peers:
                    self._peers.popitem(last=False)
            self._peers.move_to_end(msg.id)
            peer.period = msg.period_ms / 1000
            peer.origin = msg.origin
            peer.arrive(now)
            peer.sequence(msg.seq, now)
            self.probes_received += 1
            for pid, loss in zip(msg.peers, msg.loss, strict=True):
                if pid == self.id and math.isfinite(loss):
                    peer.reported, peer.reported_at = min(1.0, max(0.0, float(loss))), now

    def _incoming(self, peer: _Peer, now: float) -> float:
        # Called with the lock held and a ``now`` read under it: never earlier than any trim before.
        worst = 0.0
        for window, arrivals in ((self.window_s, peer.short), (self.long_window_s, peer.long)):
            span = min(window, now - peer.first_seen)
            if span < 4 * peer.period:
                continue          # too new to say
            got = _count_after(arrivals, window, now - span, now)
            worst = max(worst, 1.0 - min(1.0, got / (span / peer.period)))
        return worst

    def incoming_loss(self) -> dict[int, float]:
        """Per peer heard: the loss measured on its probes (0..1)."""
        with self._lock:
            now = time.monotonic()
            return {pid: self._incoming(p, now) for pid, p in self._peers.items()}

    def _of(self, origin: str | None) -> list[_Peer]:
        """The peers whose probes name ``origin`` (all peers for None, or when none does: a drone not
        heard yet is sized like the worst link heard). Called with the lock held. Of several peers
        naming one origin the worst counts, so a peer that claims another's name can raise its
        copies, never lower them."""
        peers = list(self._peers.values())
        if origin is None:
            return peers
        return [p for p in peers if p.origin == origin] or peers

    def burst(self, origin: str | None = None) -> BurstEstimate:
        """The burstiest peer heard (by the loss that follows a loss), over the long window, and the
        longest silence of a peer now; of the peers named ``origin`` when given (see ``_of``)."""
        worst: BurstEstimate | None = None
        silent = 0.0
        with self._lock:
            now = time.monotonic()
            for p in self._of(origin):
                b = p.burst(self.long_window_s, now)
                if worst is None or b.loss_after_loss > worst.loss_after_loss:
                    worst = b
                silent = max(silent, (now - p.last) / p.period)
        return replace(worst or BurstEstimate(), silent_probes=silent)

    def outgoing_loss(self, origin: str | None = None) -> float:
        """The worst loss towards any peer heard recently (NaN if none): what to size copies for; towards
        the peers named ``origin`` when given (see ``_of``)."""
        worst = math.nan
        with self._lock:
            now = time.monotonic()
            for p in self._of(origin):
                loss = self._incoming(p, now)
                if now - p.reported_at < 3.0 and math.isfinite(p.reported):
                    loss = max(loss, p.reported)
                worst = loss if math.isnan(worst) else max(worst, loss)
        return worst

    # -- send ------------------------------------------------------------------------
    def _run(self) -> None:
        next_t = time.monotonic()
        while not self._stop.is_set():
            try:
                self._tick()
            except Exception as exc:   # a closing session: never kill the thread on one failure
                now = time.monotonic()
                if now - self._last_log > 5.0:
                    self._last_log = now
                    log.warning("link probe failed: %s", exc)
            next_t += self.period_s
            self._stop.wait(max(0.0, next_t - time.monotonic()))

    def _tick(self) -> None:
        with self._lock:
            now = time.monotonic()
            gone = [pid for pid, p in self._peers.items() if now - p.last > self.forget_s]
            for pid in gone:
                del self._peers[pid]
            measured = [(pid, self._incoming(p, now)) for pid, p in self._peers.items()]
        self._seq = (self._seq + 1) & 0xFFFFFFFF
        self._pub.publish(LinkProbe(self.id, self._seq, round(self.period_s * 1000),
                                    [pid for pid, _ in measured], [loss for _, loss in measured], self.origin))
        self.probes_sent += 1
        if not measured:
            return
        loss = self.outgoing_loss()
        for adapter in self._adapters:
            try:
                adapter(loss)
            except Exception as exc:
                self.adapter_errors += 1
                if now - self._last_log > 5.0:
                    self._last_log = now
                    log.warning("loss adapter failed: %s", exc)

    def close(self) -> None:
        self._stop.set()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)
