"""Two network namespaces joined by a veth pair, with random per-frame packet loss.

tc netem is absent on these kernels, so loss is an nftables rule in each namespace:
``numgen random mod 100 < P drop`` in a prerouting chain at priority -500, below
conntrack and IP defragmentation, so every frame (each IP fragment, each TCP segment)
is dropped with probability P as netem and real Wi-Fi do. Segmentation offloads are
off on both ends so one "packet" on the wire is one frame in the rule. Each side drops
on input, so each direction loses P%.
"""
from __future__ import annotations

import os
import secrets
import shutil
import subprocess
from dataclasses import dataclass, field

TOOLS = ("ip", "nft", "ethtool")


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
    _up: bool = False

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
        """Change the drop probability on both sides at once (atomic per namespace)."""
        if not 0 <= loss_pct <= 100:
            raise ValueError(f"loss must be 0..100 %, got {loss_pct}")
        self.loss_pct = loss_pct
        for side in self.sides:
            rule = (f'iifname "{self.dev(side)}" numgen random mod 100 < {int(round(loss_pct))} drop'
                    if loss_pct > 0 else "")
            script = ("table inet zrloss\ndelete table inet zrloss\n"
                      "table inet zrloss {\n  chain pre {\n"
                      "    type filter hook prerouting priority -500; policy accept;\n"
                      f"    {rule}\n  }}\n}}\n")
            _run(*self.exec_in(side), "nft", "-f", "-", input=script)

    def tx_bytes(self, side: str) -> int:
        """Bytes ``side`` has sent on its veth so far (before the peer's loss rule drops any)."""
        import json
        out = _run("ip", "-n", self.ns(side), "-s", "-j", "link", "show", self.dev(side)).stdout
        return int(json.loads(out)[0]["stats64"]["tx"]["bytes"])

    def down(self) -> None:
        if not self._up:
            return
        for side in self.sides:
            _run("ip", "netns", "del", self.ns(side), check=False)  # removes the veth and rules too
        self._up = False

    def exists(self) -> bool:
        out = _run("ip", "netns", "list", check=False).stdout
        return any(line.split()[0] in (self.ns(s) for s in self.sides) for line in out.splitlines() if line)
