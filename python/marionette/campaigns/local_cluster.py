"""A Ray cluster on this machine, for tests and the campaign benchmark: a head without CPUs and N
worker nodes, all on 127.0.0.1 (``ray start --node-ip-address 127.0.0.1``: the nodes reach each
other over loopback; Ray's gRPC servers still listen on every interface, Ray has no bind option),
each node a ``ray start --block`` process of its own session, stopped with everything it started.

    with local_cluster(workers=2) as address:
        run_campaign(folder, settings, scenario, cluster=address)
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

from marionette.campaigns.errors import CampaignError
from marionette.campaigns.trial import child_environment

START_TIMEOUT_S = 180.0  # a node's start on a loaded machine (the head: ~15 s at load 14)
OBJECT_STORE_BYTES = 100 * 1024 * 1024


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@dataclass
class _Node:
    name: str
    popen: subprocess.Popen
    log: Path


def _start(name: str, argv: list[str], env: dict[str, str], log_dir: Path) -> _Node:
    log = log_dir / f"{name}.log"
    with open(log, "w") as f:
        popen = subprocess.Popen(
            argv,
            stdout=f,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            env=env,
            start_new_session=True,  # its own process group: stopped whole
        )
    node = _Node(name, popen, log)
    deadline = time.monotonic() + START_TIMEOUT_S
    while "Ray runtime started" not in log.read_text(errors="replace"):
        if popen.poll() is not None or time.monotonic() > deadline:
            tail = log.read_text(errors="replace").strip().splitlines()[-3:]
            _stop([node])
            raise CampaignError(f"the Ray {name} did not start: {' / '.join(tail)}")
        time.sleep(0.5)
    return node


def _stop(nodes: list[_Node], timeout_s: float = 30.0) -> None:
    """SIGTERM to each node (``ray start --block`` stops its processes), then SIGKILL to the
    process group of any still there."""
    for node in reversed(nodes):
        if node.popen.poll() is None:
            node.popen.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + timeout_s
    for node in reversed(nodes):
        with contextlib.suppress(subprocess.TimeoutExpired):
            node.popen.wait(max(0.1, deadline - time.monotonic()))
        with contextlib.suppress(ProcessLookupError, PermissionError):
            os.killpg(node.popen.pid, signal.SIGKILL)  # what outlived it in its group
        node.popen.wait()


@contextlib.contextmanager
def local_cluster(
    workers: int = 2, cpus_per_worker: int = 1, log_dir: Path | None = None
) -> Iterator[str]:
    """Starts the head and ``workers`` nodes of ``cpus_per_worker`` CPUs (environment: this
    marionette and its build, :func:`.trial.child_environment`); yields the head's address;
    stops them all."""
    ray = str(Path(sys.executable).parent / "ray")
    temp = Path(tempfile.mkdtemp(prefix="ray", dir="/tmp"))  # short: Ray's socket paths
    log_dir = Path(log_dir or temp)
    log_dir.mkdir(parents=True, exist_ok=True)
    env = {**child_environment(), "RAY_TMPDIR": str(temp)}
    common = ["--node-ip-address", "127.0.0.1", "--block", "--disable-usage-stats"]
    common += ["--object-store-memory", str(OBJECT_STORE_BYTES)]
    port = _free_port()
    nodes: list[_Node] = []
    try:
        nodes.append(
            _start(
                "head",
                [
                    ray,
                    "start",
                    "--head",
                    "--port",
                    str(port),
                    "--num-cpus",
                    "0",
                    *common,
                    "--include-dashboard",
                    "false",
                    "--temp-dir",
                    str(temp),
                    "--ray-client-server-port",
                    str(_free_port()),
                    "--dashboard-agent-listen-port",
                    str(_free_port()),
                ],
                env,
                log_dir,
            )
        )
        for i in range(workers):  # one after the other: started together, one timed out
            nodes.append(
                _start(
                    f"worker{i + 1}",
                    [
                        ray,
                        "start",
                        "--address",
                        f"127.0.0.1:{port}",
                        "--num-cpus",
                        str(cpus_per_worker),
                        *common,
                        "--dashboard-agent-listen-port",
                        str(_free_port()),
                    ],
                    env,
                    log_dir,
                )
            )
        yield f"127.0.0.1:{port}"
    finally:
        _stop(nodes)
