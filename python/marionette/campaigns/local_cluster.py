"""A Ray cluster on this machine, for tests and the campaign benchmark: a head without CPUs and N
worker nodes, all on 127.0.0.1 (``ray start --node-ip-address 127.0.0.1``: the nodes reach each
other over loopback; Ray's gRPC servers still listen on every interface, Ray has no bind option),
each node a ``ray start --block`` process of its own session, stopped with everything it started.

    with local_cluster(workers=2) as cluster:
        run_campaign(folder, settings, scenario, cluster=cluster.address)
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
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


@dataclass
class LocalCluster:
    """``address`` of the head; ``leftover``: after the stop, the pids of the processes the
    cluster started that outlived its nodes (killed then; a clean stop leaves it empty)."""

    address: str
    leftover: list[int] = field(default_factory=list)


@contextlib.contextmanager
def local_cluster(
    workers: int = 2, cpus_per_worker: int = 1, log_dir: Path | None = None
) -> Iterator[LocalCluster]:
    """Starts the head and ``workers`` nodes of ``cpus_per_worker`` CPUs (environment: this
    marionette and its build, :func:`.trial.child_environment`); yields the cluster; stops them
    all."""
    ray = str(Path(sys.executable).parent / "ray")
    temp = Path(tempfile.mkdtemp(prefix="ray", dir="/tmp"))  # short: Ray's socket paths
    log_dir = Path(log_dir) if log_dir is not None else temp
    log_dir.mkdir(parents=True, exist_ok=True)
    # TMPDIR marks every process the cluster starts (Ray's, the trials' and theirs): the ones
    # still there after the nodes stopped are found by it and killed.
    (temp / "tmp").mkdir()
    env = {**child_environment(), "RAY_TMPDIR": str(temp), "TMPDIR": str(temp / "tmp")}
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
        cluster = LocalCluster(f"127.0.0.1:{port}")
        yield cluster
    finally:
        _stop(nodes)
        leftover = processes_with_env("TMPDIR", env["TMPDIR"])
        for pid in leftover:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        if nodes and len(nodes) == workers + 1:
            cluster.leftover = leftover
        if log_dir != temp:
            shutil.rmtree(temp, ignore_errors=True)  # Ray's session files


def processes_with_env(key: str, value: str) -> list[int]:
    """The pids of the processes (but this one) whose environment has ``key=value``."""
    marker = f"{key}={value}".encode()
    out = []
    for proc in Path("/proc").iterdir():
        if not proc.name.isdigit() or int(proc.name) == os.getpid():
            continue
        try:
            if marker in (proc / "environ").read_bytes().split(b"\0"):
                out.append(int(proc.name))
        except OSError:
            continue
    return out
