"""Two network namespaces joined by a veth pair, with random per-frame packet loss.

tc netem is absent on these kernels, so loss is an nftables rule in each namespace:
``numgen random mod 100 < P drop`` in a prerouting chain at priority -500, below
conntrack and IP defragmentation, so every frame (each IP fragment, each TCP segment)
is dropped with probability P as netem and real Wi-Fi do. Segmentation offloads are
off on both ends so one "packet" on the wire is one frame in the rule. Each side drops
on input, so each direction loses P%.

Two loss models (``loss_model``):
- ``uniform``: every frame is dropped with probability P, independently (the thesis's netem).
- ``bursty``: a two-state (Gilbert-Elliott) channel at the same mean P. ``numgen random`` has no
  memory, so a controller thread (:class:`BurstyChannel`) swaps the rule's drop probability
  between a good state (``good_pct``, at most 5 %) and a bad one (``bad_pct``, 95 %): bad periods
  last ``bad_mean_s`` on average (exponential, clamped to ``bad_min_s``..``bad_max_s``: fades of
  100 ms to 2 s), good periods are exponential with the mean that makes the time-weighted loss P.
  One state for both directions (a radio fade is both ways). Every swap is recorded with its
  time (``link.timeline``: the raw data of what was applied); :meth:`LossyLink.applied_loss` is the
  time-weighted loss over a window of it.
"""
from __future__ import annotations

import math
import os
import random
import secrets
import shutil
import subprocess
import threading
import time
from dataclasses import dataclass, field
from typing import Any

TOOLS = ("ip", "nft", "ethtool")
LOSS_MODELS = ("uniform", "bursty")


@dataclass(frozen=True)
class BurstModel:
    """The bursty channel's parameters (the mean loss is the link's ``loss_pct``)."""
    bad_pct: float = 95.0
    good_max_pct: float = 5.0       # the good state's loss: min(this, mean / 2)
    bad_mean_s: float = 0.3
    bad_min_s: float = 0.1
    bad_max_s: float = 2.0
    good_min_s: float = 0.02        # below this a swap (two `nft -f` runs) is not worth applying
    seed: int | None = None

    def states(self, mean_pct: float) -> tuple[float, float, float]:
        """(good %, bad %, mean good period s) giving ``mean_pct`` on average; mean good period
        inf when the mean needs no bad state, 0 when it needs nothing else."""
        good = min(self.good_max_pct, mean_pct / 2)
        bad = max(self.bad_pct, mean_pct)
        if mean_pct <= good:
            return good, bad, math.inf
        share = min(1.0, (mean_pct - good) / (bad - good))     # of the time in the bad state
        if share >= 1.0:
            return good, bad, 0.0
        return good, bad, self.bad_mean() * (1 - share) / share

    def bad_mean(self) -> float:
        """The mean of the clamped exponential bad period (what the good periods are sized against)."""
        m, lo, hi = self.bad_mean_s, self.bad_min_s, self.bad_max_s
        return lo + m * (math.exp(-lo / m) - math.exp(-hi / m))


class NetnsUnavailable(RuntimeError):
    """Namespaces cannot be built here; the message says why (root, a missing tool, the kernel)."""


def unavailable_reason() -> str | None:
    """None if this process can build lossy namespaces, else one line saying why not."""
    if os.geteuid() != 0:
        return "needs root to create network namespaces and nftables rules (run as root, e.g. in CI)"
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if missing:
        return f"missing {', '.join(missing)} (install nftables, iproute2 and ethtool: `make sysdeps`)"
    return None


def _run(*cmd: str, input: str | None = None, check: bool = True) -> subprocess.CompletedProcess[str]:
    res = subprocess.run(cmd, input=input, capture_output=True, text=True)
    if check and res.returncode != 0:
        raise NetnsUnavailable(f"`{' '.join(cmd)}` failed: {res.stderr.strip() or res.stdout.strip()}")
    return res


@dataclass
class LossyLink:
    """``with LossyLink(loss_pct=10) as link: subprocess.run(link.exec_in("gcs") + [...])``.

    Namespaces ``<prefix>-gcs`` and ``<prefix>-drone`` get 10.77.<n>.1 and .2; everything
    is removed on exit, on error and on Ctrl-C (the with-block's exit runs for all three).
    """
    loss_pct: float = 0.0
    prefix: str = field(default_factory=lambda: f"zr{secrets.token_hex(3)}")
    subnet: int = field(default_factory=lambda: secrets.randbelow(200) + 20)
    sides: tuple[str, str] = ("gcs", "drone")
    loss_model: str = "uniform"
    burst: BurstModel = field(default_factory=BurstModel)
    # (time ns, state, drop % applied): every change of the rule, both loss models.
    timeline: list[tuple[int, str, float]] = field(default_factory=list)
    _up: bool = False
    _channel: "BurstyChannel | None" = None

    def ns(self, side: str) -> str:
        return f"{self.prefix}-{side}"

    def dev(self, side: str) -> str:
        return f"{self.prefix}{side[0]}0"   # interface names are limited to 15 characters

    def addr(self, side: str) -> str:
        return f"10.77.{self.subnet}.{self.sides.index(side) + 1}"

    def exec_in(self, side: str) -> list[str]:
        return ["ip", "netns", "exec", self.ns(side)]

    def __enter__(self) -> "LossyLink":
        self.up()
        return self

    def __exit__(self, *exc: object) -> None:
        self.down()

    def up(self) -> None:
        reason = unavailable_reason()
        if reason:
            raise NetnsUnavailable(reason)
        a, b = self.sides
        try:
            self._up = True
            for side in self.sides:
                _run("ip", "netns", "add", self.ns(side))
            _run("ip", "link", "add", self.dev(a), "type", "veth", "peer", "name", self.dev(b))
            for side in self.sides:
                _run("ip", "link", "set", self.dev(side), "netns", self.ns(side))
                _run("ip", "-n", self.ns(side), "addr", "add", f"{self.addr(side)}/24", "dev", self.dev(side))
                _run("ip", "-n", self.ns(side), "link", "set", self.dev(side), "up")
                _run("ip", "-n", self.ns(side), "link", "set", "lo", "up")
                # Multicast (Zenoh scouting, the multicast transport) routes out of the veth.
                _run("ip", "-n", self.ns(side), "route", "add", "224.0.0.0/4", "dev", self.dev(side))
                _run(*self.exec_in(side), "ethtool", "-K", self.dev(side), "tso", "off", "gso", "off",
                     "gro", "off", check=False)   # some offloads are fixed on veth: best effort
            self.set_loss(self.loss_pct)
        except BaseException:
            self.down()
            raise

    def set_loss(self, loss_pct: float) -> None:
        """Set the mean loss: the uniform drop probability on both sides at once (atomic per
        namespace), or the bursty channel's mean (its controller thread is started or stopped)."""
        if not 0 <= loss_pct <= 100:
            raise ValueError(f"loss must be 0..100 %, got {loss_pct}")
        if self.loss_model not in LOSS_MODELS:
            raise ValueError(f"loss model {self.loss_model!r}: one of {', '.join(LOSS_MODELS)}")
        self.loss_pct = loss_pct
        if self._channel is not None:
            self._channel.stop()
            self._channel = None
        if self.loss_model == "bursty" and loss_pct > 0:
            self._channel = BurstyChannel(self, loss_pct)
            self._channel.start()
            return
        self._apply(loss_pct, "uniform" if loss_pct > 0 else "clean")

    def _apply(self, loss_pct: float, state: str) -> None:
        """Put ``loss_pct`` in both namespaces' rule and record it in the timeline."""
        for side in self.sides:
            rule = (f'iifname "{self.dev(side)}" numgen random mod 100 < {int(round(loss_pct))} drop'
                    if loss_pct > 0 else "")
            script = ("table inet zrloss\ndelete table inet zrloss\n"
                      "table inet zrloss {\n  chain pre {\n"
                      "    type filter hook prerouting priority -500; policy accept;\n"
                      f"    {rule}\n  }}\n}}\n")
            _run(*self.exec_in(side), "nft", "-f", "-", input=script)
        self.timeline.append((time.time_ns(), state, loss_pct))

    def applied_loss(self, t0_ns: int, t1_ns: int) -> float | None:
        """The time-weighted drop % the rule had over [t0, t1] (None: nothing applied before t1)."""
        total = weighted = 0.0
        marks = self.timeline
        for i, (t, _, pct) in enumerate(marks):
            end = marks[i + 1][0] if i + 1 < len(marks) else t1_ns
            a, b = max(t, t0_ns), min(end, t1_ns)
            if b > a:
                total += b - a
                weighted += (b - a) * pct
        return weighted / total if total else None

    def timeline_summary(self, t0_ns: int, t1_ns: int) -> dict[str, Any]:
        """What the channel applied over [t0, t1]: mean loss, bad periods (count, mean, longest)."""
        bad: list[float] = []
        marks = self.timeline
        for i, (t, state, _) in enumerate(marks):
            end = marks[i + 1][0] if i + 1 < len(marks) else t1_ns
            a, b = max(t, t0_ns), min(end, t1_ns)
            if state == "bad" and b > a:
                bad.append((b - a) / 1e9)
        applied = self.applied_loss(t0_ns, t1_ns)
        return {"model": self.loss_model, "mean_pct": None if applied is None else round(applied, 2),
                "bad_periods": len(bad), "bad_mean_s": round(sum(bad) / len(bad), 3) if bad else None,
                "bad_longest_s": round(max(bad), 3) if bad else None,
                "bad_share": round(sum(bad) / max(1e-9, (t1_ns - t0_ns) / 1e9), 3)}

    def tx_bytes(self, side: str) -> int:
        """Bytes ``side`` has sent on its veth so far (before the peer's loss rule drops any)."""
        import json
        out = _run("ip", "-n", self.ns(side), "-s", "-j", "link", "show", self.dev(side)).stdout
        return int(json.loads(out)[0]["stats64"]["tx"]["bytes"])

    def down(self) -> None:
        if self._channel is not None:
            self._channel.stop()
            self._channel = None
        if not self._up:
            return
        for side in self.sides:
            _run("ip", "netns", "del", self.ns(side), check=False)  # removes the veth and rules too
        self._up = False

    def exists(self) -> bool:
        out = _run("ip", "netns", "list", check=False).stdout
        return any(line.split()[0] in (self.ns(s) for s in self.sides) for line in out.splitlines() if line)


class BurstyChannel:
    """Drives a LossyLink's rule between the good and the bad state (see the module doc).

    Threads: its own (daemon) thread runs the swaps; ``start``/``stop`` from the link's owner.
    A swap that fails (the namespaces are going away) ends the thread; the link stays as it was.
    """

    def __init__(self, link: LossyLink, mean_pct: float) -> None:
        self.link, self.mean_pct = link, mean_pct
        self.model = link.burst
        self._rng = random.Random(self.model.seed)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="zr-bursty-loss", daemon=True)
        self.error: str | None = None

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout=5.0)

    def _bad_period(self) -> float:
        m = self.model
        return min(m.bad_max_s, max(m.bad_min_s, self._rng.expovariate(1 / m.bad_mean_s)))

    def _run(self) -> None:
        good, bad, good_mean = self.model.states(self.mean_pct)
        try:
            if math.isinf(good_mean):           # too little loss for a fade: a good state only
                self.link._apply(good, "good")
                return
            state = "good" if good_mean > 0 and self._rng.random() < good_mean / (good_mean + self.model.bad_mean()) \
                else "bad"
            applied = ""
            while not self._stop.is_set():
                if state == "bad":
                    if applied != "bad":        # after a good period too short to apply, the fade goes on
                        self.link._apply(bad, "bad")
                        applied = "bad"
                    period = self._bad_period()
                else:
                    period = self._rng.expovariate(1 / good_mean) if good_mean > 0 else 0.0
                    if period >= self.model.good_min_s:
                        self.link._apply(good, "good")
                        applied = "good"
                    else:
                        period = 0.0
                if period > 0 and self._stop.wait(period):
                    return
                state = "good" if state == "bad" else "bad"
        except NetnsUnavailable as exc:
            self.error = str(exc)
