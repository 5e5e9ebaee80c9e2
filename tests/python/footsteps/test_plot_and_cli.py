"""The plotting helper and `marionette footsteps plan`."""

from __future__ import annotations

import subprocess
import sys

import matplotlib.image as mpimg
import numpy as np
import pytest

from footsteps_checks import TALOS_FOOT
from marionette.footsteps.obstacles import Bar, CircleObstacle
from marionette.footsteps.step_over import StepOverPlanner


def test_plot_writes_a_top_view_with_the_plan_drawn(tmp_path, stance):
    bar = Bar([1.0, 0.0], np.pi / 2, 0.02, 1.0)
    planner = StepOverPlanner(stance, [2.0, 0.0, 0.0], bar, TALOS_FOOT)
    planner.plan()
    earlier = planner.result()
    planner.update_bar(bar.moved_to([1.05, 0.03], np.pi / 2 + 0.1))
    from marionette.footsteps.plot import plot_plan

    path = plot_plan(
        tmp_path / "plan.png",
        planner.result(),
        planner.foot,
        [planner.bar, CircleObstacle([0.5, 0.4], 0.1)],
        goal=[2.0, 0.0, 0.0],
        hand_target=np.array([2.2, 0.0, 0.6]),
        earlier=[earlier],
        title="test",
    )
    image = mpimg.imread(path)
    assert image.shape[0] > 300 and image.shape[1] > 500
    rgb = image[..., :3]
    # Left soles (tab:blue), right soles (tab:red) and the bar (tab:orange) are drawn.
    for color in ([0.12, 0.47, 0.71], [0.84, 0.15, 0.16], [1.0, 0.5, 0.05]):
        assert np.any(np.all(np.abs(rgb - color) < 0.06, axis=-1)), color


@pytest.mark.slow
def test_cli_plans_a_step_over_and_writes_the_figure(tmp_path, lcm_env):
    png = tmp_path / "step_over.png"
    out = subprocess.run(
        [
            sys.executable,
            "-m",
            "marionette.cli",
            "footsteps",
            "plan",
            "--mode",
            "step-over",
            "--bar-pose",
            "1.0",
            "0.0",
            "1.5708",
            "--png",
            str(png),
        ],
        env=lcm_env,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 0, out.stderr
    assert "converged=True" in out.stdout
    assert out.stdout.count("via=") == 2
    assert png.stat().st_size > 10_000
