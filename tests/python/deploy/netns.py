"""Two hosts on one machine: network namespaces joined by a veth pair, with a multicast route.

Each namespace has its own interfaces and routes, so LCM's UDP multicast between them crosses a
real (virtual) Ethernet link exactly as between two computers: the URL needs ``ttl=1`` and each
side a route for the LCM group on the link's interface (what README.md tells users to do).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
from collections.abc import Iterator
from dataclasses import dataclass

LCM_GROUP_ROUTE = "239.255.76.0/24"


class NetnsUnavailable(RuntimeError):
    """Namespaces cannot be made here (not root, no `ip`, no veth support): the reason says
    which."""


@dataclass(frozen=True)
class Host:
    name: str
    address: str

    def command(self, argv: list[str]) -> list[str]:
        """``argv`` run inside this host's namespace."""
        return ["ip", "netns", "exec", self.name, *argv]


def _ip(*args: str) -> None:
    done = subprocess.run(["ip", *args], capture_output=True, text=True)
    if done.returncode != 0:
        raise NetnsUnavailable(f"`ip {' '.join(args)}` failed: {done.stderr.strip()}")


@contextlib.contextmanager
def two_hosts(tag: str | None = None) -> Iterator[tuple[Host, Host]]:
    """Creates hosts A (10.213.0.1) and B (10.213.0.2) on one veth link; removes them after."""
    if os.geteuid() != 0:
        raise NetnsUnavailable("network namespaces need root (run the tests as root, as CI does)")
    if shutil.which("ip") is None:
        raise NetnsUnavailable("the `ip` command (iproute2) is missing")
    tag = tag or str(os.getpid())
    a, b = Host(f"mrnA{tag}", "10.213.0.1"), Host(f"mrnB{tag}", "10.213.0.2")
    made: list[str] = []
    try:
        for host in (a, b):
            _ip("netns", "add", host.name)
            made.append(host.name)
        _ip("link", "add", f"va{tag}"[:15], "type", "veth", "peer", "name", f"vb{tag}"[:15])
        for host, dev in ((a, f"va{tag}"[:15]), (b, f"vb{tag}"[:15])):
            _ip("link", "set", dev, "netns", host.name)
            _ip("-n", host.name, "addr", "add", f"{host.address}/24", "dev", dev)
            _ip("-n", host.name, "link", "set", dev, "up", "multicast", "on")
            _ip("-n", host.name, "link", "set", "lo", "up")
            _ip("-n", host.name, "route", "add", LCM_GROUP_ROUTE, "dev", dev)
        yield a, b
    finally:
        for name in made:  # deleting a namespace deletes its end of the veth pair, and the pair
            subprocess.run(["ip", "netns", "del", name], capture_output=True)
