"""Generated Python types round-trip, and a C++ publisher reaches a Python subscriber."""

from __future__ import annotations

import socket
import subprocess

import numpy as np

from marionette import channels, lcmt_controller_spec, lcmt_robot_state, lcmt_task_spec
from marionette.lcm_bus import LcmBus, MessageLog, udp_receive_buffer_drops


def test_python_round_trip_keeps_every_field():
    spec = lcmt_controller_spec()
    spec.utime = 12
    spec.controller_id = 4
    spec.name = "grasp"
    spec.max_switch_velocity_jump = 0.1
    task = lcmt_task_spec()
    task.name = "right_gripper"
    task.kind = "se3"
    task.frame = "gripper_right_joint"
    task.mask = [True, True, True, False, False, True]
    task.gain = 2.5
    task.num_reference = 7
    task.reference = [0.1, 0.2, 0.3, 1.0, 0.0, 0.0, 0.0]
    spec.tasks = [task]
    spec.num_tasks = 1
    out = lcmt_controller_spec.decode(spec.encode())
    assert out.name == "grasp" and out.controller_id == 4
    assert out.tasks[0].mask == [True, True, True, False, False, True]
    assert list(out.tasks[0].reference) == task.reference


def test_decode_of_wrong_type_raises():
    state = lcmt_robot_state()
    try:
        lcmt_controller_spec.decode(state.encode())
    except ValueError:
        return
    raise AssertionError("decoding a robot state as a controller spec must fail")


def test_cpp_publisher_reaches_python_subscriber(build_dir, lcm_url):
    with LcmBus(lcm_url) as bus:
        log = MessageLog(bus, channels.ROBOT_STATE, lcmt_robot_state)
        bus.start()
        proc = subprocess.run(
            [str(build_dir / "lcm_publish_messages"), lcm_url, "30"], timeout=30, check=True
        )
        assert proc.returncode == 0
        assert log.wait_for(lambda m: len(m) >= 25, timeout_s=5.0), f"got {len(log.messages)}"
    assert bus.decode_errors == {}
    for msg in log.messages:
        assert msg.robot_name == "cpp-publisher"
        assert msg.joint_name == [f"joint_{j}" for j in range(4)]
        np.testing.assert_allclose(msg.joint_position, [msg.tick + 0.25 * j for j in range(4)])
        assert msg.utime == 1000 * msg.tick


def test_private_urls_avoid_ports_held_elsewhere_and_the_ephemeral_range():
    """A port another socket holds without address reuse cannot be bound by LCM ("bind:
    Address already in use": the bus then receives nothing): such a port is skipped, and
    ports come from below the kernel's ephemeral range (where outgoing sockets land)."""
    import socket

    from marionette.lcm_bus import _ephemeral_port_floor, private_lcm_url

    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # no SO_REUSEADDR
    holder.bind(("", 0))
    held = holder.getsockname()[1]
    free_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    free_sock.bind(("", 0))
    free = free_sock.getsockname()[1]
    free_sock.close()

    class Picks:  # the ports a random generator would draw, in order
        def __init__(self, ports):
            self.ports = list(ports)

        def randrange(self, lo, hi):
            return self.ports.pop(0)

    try:
        assert private_lcm_url(Picks([held, free])).endswith(f":{free}?ttl=0")
    finally:
        holder.close()
    floor = _ephemeral_port_floor()
    for _ in range(200):
        port = int(private_lcm_url().split(":")[-1].split("?")[0])
        assert 20000 <= port < max(floor, 21000)


def test_udp_receive_buffer_drops_counts_datagrams_a_full_socket_lost():
    # A socket with the smallest receive buffer, never read, overflows: the kernel counts each
    # datagram it dropped, and the count is what a demo reports as lost by its LCM processes.
    before = udp_receive_buffer_drops()
    assert before is not None and before >= 0
    with (
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as rx,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx,
    ):
        rx.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1)
        rx.bind(("127.0.0.1", 0))
        for _ in range(200):
            tx.sendto(b"x" * 8000, rx.getsockname())
    assert udp_receive_buffer_drops() - before >= 150
