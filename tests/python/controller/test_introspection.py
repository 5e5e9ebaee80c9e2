"""``marionette dg`` against a running controller: the listing and the dot graph describe the
graph it runs, values read match what the graph computes, only settable inputs can be set, a
1 kHz trace gets every tick and leaves the tick timing unchanged."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

import marionette
from marionette.control.introspection import GraphClient, IntrospectionError
from marionette.control.spec import ControllerSpec, TaskSpec

UR10 = ["--robot", "ur10", "--backend", "kinematic", "--camera-rate", "0", "--status-rate", "5"]


def arm(controller_id: int, gain: float = 1.0) -> ControllerSpec:
    return ControllerSpec(
        controller_id,
        f"arm{controller_id}",
        [
            TaskSpec("tool", "se3", 0, frame="tool0", gain=gain),
            TaskSpec("posture", "posture", 1, gain=gain),
        ],
    )


@pytest.mark.slow
def test_ls_get_set_graph_and_cli(run_controller, lcm_url, lcm_env):
    with run_controller(*UR10) as c, GraphClient(lcm_url) as dg:
        c.send_spec(arm(1))
        c.wait(lambda c: c.status.active_controller_id == 1, 20, "controller 1")
        listing = dg.ls()
        for line in (
            "command (KinematicDevice)",
            "safety (SafetyFilter)",
            "c1_solver (Solver)",
            "input velocity : vector 7x1 <- c1_solver.velocity",
        ):
            assert line in listing, listing
        dot = dg.dot()
        assert '"c1_solver":"velocity":e -> "safety":"velocity":w' in dot
        # Values: the commanded configuration the graph integrates equals the published command.
        tick, values = dg.get_with_tick("command.configuration", "c1_posture.gain")
        assert values["command.configuration"].shape == (7,)
        np.testing.assert_allclose(
            values["command.configuration"], c.command.joint_position, atol=1e-3
        )
        assert float(values["c1_posture.gain"]) == 1.0 and tick > 0
        # Only settable inputs: a gain yes, the safety mode and an output no.
        dg.set("c1_posture.gain", 3.5)
        _, values = dg.get_with_tick("c1_posture.gain")
        assert float(values["c1_posture.gain"]) == 3.5
        with pytest.raises(IntrospectionError, match=r"safety\.mode is not settable"):
            dg.set("safety.mode", 0)
        with pytest.raises(IntrospectionError, match="is an output"):
            dg.set("c1_solver.velocity", np.zeros(7))
        with pytest.raises(IntrospectionError, match="takes 1 values, 2 given"):
            dg.set("c1_posture.gain", [1.0, 2.0])
        with pytest.raises(IntrospectionError, match="no entity 'nobody'"):
            dg.get("nobody.out")
        # The command line, as a user types it.
        out = subprocess.run(
            [
                str(marionette.REPO_ROOT / ".venv/bin/marionette"),
                "dg",
                "--lcm-url",
                lcm_url,
                "get",
                "c1_posture.gain",
            ],
            capture_output=True,
            text=True,
            env=lcm_env,
            timeout=30,
        )
        assert out.returncode == 0, out.stderr
        assert "c1_posture.gain = 3.5" in out.stdout
        refused = subprocess.run(
            [
                str(marionette.REPO_ROOT / ".venv/bin/marionette"),
                "dg",
                "--lcm-url",
                lcm_url,
                "set",
                "safety.mode",
                "0",
            ],
            capture_output=True,
            text=True,
            env=lcm_env,
            timeout=30,
        )
        assert refused.returncode == 1 and "not settable" in refused.stderr


@pytest.mark.slow
def test_trace_at_1khz_gets_every_tick_and_timing_is_unchanged(run_controller, lcm_url):
    # As deployed: the loop at SCHED_FIFO 80, the LCM thread that serves the trace at 40. At normal
    # priority on 2 cores the loop shares the CPU with this test's receiver of 1000 samples/s, and
    # the comparison measures that, not what tracing costs the loop.
    with run_controller(*UR10, "--realtime") as c, GraphClient(lcm_url) as dg:
        c.send_spec(arm(1))
        c.wait(lambda c: c.status.active_controller_id == 1, 20, "controller 1")
        c.wait_time(2.0)
        quiet_start = c.status
        c.wait_time(3.0)
        before = c.status  # the same 3 s without a trace: what this machine misses anyway
        samples = list(
            dg.trace(["command.configuration", "c1_solver.velocity"], rate=1000, duration=3.0)
        )
        c.wait_time(0.5)
        during = c.status  # windows of 10 s: mostly ticks with the trace on
        ticks = [s.tick for s in samples]
        assert len(ticks) > 2000
        assert np.all(np.diff(ticks) == 1), "a sample for every tick, none lost"
        # The integrated command follows the traced velocity: q[k+1] = q[k] + v[k] dt.
        q = np.array([s.values["command.configuration"] for s in samples])
        v = np.array([s.values["c1_solver.velocity"] for s in samples])
        np.testing.assert_allclose(q[1:], q[:-1] + 1e-3 * v[:-1], atol=1e-12)
        # Tracing costs the loop a few copies: its timing is unchanged (noisy machines: loose). The
        # grant is read from the log now, seconds after start-up, not as the process may still print
        # it.
        realtime = "loop thread real-time: SCHED_FIFO priority 80 granted" in c.process.log_tail(50)
        if not realtime:
            pytest.skip(
                "SCHED_FIFO refused (needs root or CAP_SYS_NICE): the timing comparison needs it; "
                "samples checked"
            )
        # A virtual machine's vCPU is itself preempted by its host: SCHED_FIFO in the guest cannot
        # stop that, so misses are compared with those of the quiet window just before, not with 0.
        quiet_misses = before.deadline_misses - quiet_start.deadline_misses
        traced_misses = during.deadline_misses - before.deadline_misses
        assert during.compute.p99_us <= 2.0 * before.compute.p99_us + 100.0
        assert traced_misses <= 2 * quiet_misses + 0.01 * 3000 + 20, (quiet_misses, traced_misses)
