"""RANGE_FINDERS: the MuJoCo scene's rangefinder sensors, published by marionette-controller and
marionette-sim with the state (same utime), against the closed form of a beam meeting the floor;
-1 for a beam that meets nothing; no channel for a scene without range finders."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from marionette import BUILD_DIR, channels, lcmt_range_finders, lcmt_robot_state, robots
from marionette.lcm_bus import LcmBus, MessageLog, private_lcm_url
from marionette.processes import ProcessGroup
from marionette.scenarios.perturbations import write_scene

ROBOT = "panda"  # fixed base, far from the mount below (reach < 1 m)
MOUNT = (2.0, 0.0, 0.8)  # a static body above the floor (z = 0) [m]
TILT = math.radians(30.0)  # the tilted beam: from straight down toward +x
# The tilted beam meets the floor after height / cos(tilt); the upward one meets nothing.
EXPECTED = {"range_tilted": MOUNT[2] / math.cos(TILT), "range_up": -1.0}


def _scene(out: Path, noise: float = 0.0) -> Path:
    """The robot's MJCF with two range finders on a static mount (its own body: a rangefinder
    ignores its site's body, and the world body holds the floor), both declaring ``noise``."""
    source = robots.robot(ROBOT).mjcf
    text = source.read_text()
    mount = (
        f'<body name="range_mount" pos="{MOUNT[0]} {MOUNT[1]} {MOUNT[2]}">'
        f'<site name="range_tilted" zaxis="{math.sin(TILT):.12f} 0 {-math.cos(TILT):.12f}" />'
        '<site name="range_up" zaxis="0 0 1" /></body>'
    )
    sensors = (
        f'<sensor><rangefinder name="range_tilted" site="range_tilted" noise="{noise}" />'
        f'<rangefinder name="range_up" site="range_up" noise="{noise}" /></sensor>'
    )
    text, n = re.subn(r"</worldbody>", mount + "</worldbody>", text, count=1)
    assert n == 1
    text, n = re.subn(r"</mujoco>", sensors + "</mujoco>", text, count=1)
    assert n == 1
    return write_scene(text, source, out)


def _check(ranges: list, robot_name: str) -> None:
    assert ranges
    for msg in ranges:
        assert msg.robot_name == robot_name
        assert msg.num_sensors == 2 and list(msg.name) == list(EXPECTED)
        for name, distance in zip(msg.name, msg.distance):
            assert distance == pytest.approx(EXPECTED[name], abs=1e-9), name


@pytest.mark.slow
def test_controller_publishes_the_scene_range_finders_with_the_state(run_controller, tmp_path):
    scene = _scene(tmp_path / "scene.xml")
    with run_controller(
        "--robot", ROBOT, "--scene", str(scene), "--camera-rate", "0", "--state-rate", "200"
    ) as c:
        states = MessageLog(c.bus, channels.ROBOT_STATE, lcmt_robot_state)
        ranges = MessageLog(c.bus, channels.RANGE_FINDERS, lcmt_range_finders)
        assert ranges.wait_for(lambda msgs: len(msgs) >= 20, 10.0), c.process.log_tail()
        got = list(ranges.messages)
        published = {m.utime for m in states.messages}
    _check(got, ROBOT)
    # One publication: the state's utime (ROBOT_STATE goes out just before; the first reading
    # may have come before the state subscription).
    assert all(m.utime in published for m in got[1:]), "RANGE_FINDERS utime is not a state's"
    assert len({m.utime for m in got}) == len(got), "a snapshot published twice"


@pytest.mark.slow
def test_the_declared_noise_is_added_with_its_sigma_and_a_miss_stays_a_miss(
    run_controller, tmp_path
):
    """MJCF ``noise`` = 2 mm: over 400 readings the tilted beam's mean is the closed form within
    4 standard errors and its standard deviation 2 mm within 15 %; the upward beam still reads -1
    (no noise on "nothing hit")."""
    sigma = 0.002
    scene = _scene(tmp_path / "scene.xml", noise=sigma)
    with run_controller(
        "--robot", ROBOT, "--scene", str(scene), "--camera-rate", "0", "--state-rate", "500"
    ) as c:
        ranges = MessageLog(c.bus, channels.RANGE_FINDERS, lcmt_range_finders)
        assert ranges.wait_for(lambda msgs: len(msgs) >= 400, 20.0), c.process.log_tail()
        got = list(ranges.messages)
    tilted = np.array([m.distance[0] for m in got])
    assert all(m.distance[1] == -1.0 for m in got)
    assert abs(tilted.mean() - EXPECTED["range_tilted"]) < 4 * sigma / np.sqrt(len(tilted))
    assert tilted.std() == pytest.approx(sigma, rel=0.15)
    assert len(np.unique(tilted)) > 0.9 * len(tilted), "a new draw per reading"


@pytest.mark.slow
def test_no_range_finders_no_channel(run_controller):
    with run_controller("--robot", ROBOT, "--camera-rate", "0") as c:
        ranges = MessageLog(c.bus, channels.RANGE_FINDERS, lcmt_range_finders)
        states = MessageLog(c.bus, channels.ROBOT_STATE, lcmt_robot_state)
        assert states.wait_for(lambda msgs: len(msgs) >= 50, 10.0)
    assert not ranges.messages


@pytest.mark.slow
def test_sim_publishes_the_scene_range_finders(tmp_path):
    scene = _scene(tmp_path / "scene.xml")
    url = private_lcm_url()
    with ProcessGroup(url, tmp_path / "logs") as group, LcmBus(url, key=False) as bus:
        ranges = MessageLog(bus, channels.RANGE_FINDERS, lcmt_range_finders)
        bus.start()
        proc = group.start(
            "sim",
            [BUILD_DIR / "marionette-sim", "--robot", ROBOT, "--lcm-url", url, "--speed", "1"]
            + ["--camera-rate", "0", "--scene", str(scene)],
        )
        assert ranges.wait_for(lambda msgs: len(msgs) >= 10, 20.0), proc.log_tail()
        got = list(ranges.messages)
    _check(got, ROBOT)
    assert all(m.utime % 1000 == 0 for m in got), "not a cycle's utime"
