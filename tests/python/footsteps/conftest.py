"""Shared fixtures of the footstep tests: the walking robot once per session, one initial grasp
plan."""

from __future__ import annotations

import numpy as np
import pytest

from footsteps_checks import BALL
from marionette.footsteps.augmented_robot import Stance
from marionette.footsteps.robot_model import walking_robot


@pytest.fixture(scope="session")
def robot():
    return walking_robot("talos")


@pytest.fixture(scope="session")
def stance() -> Stance:
    return Stance(np.array([0.0, 0.085, 0.0]), np.array([0.0, -0.085, 0.0]))


@pytest.fixture(scope="session")
def grasp_planner_factory(robot, stance):
    """A GraspPlanner for BALL with its initial plan computed once; each call returns a planner
    restored to that initial plan."""
    from marionette.footsteps.planner import GraspPlanner

    planner = GraspPlanner(robot, stance, BALL)
    report = planner.plan()
    initial = planner.config.copy()

    def make():
        planner.config = initial.copy()
        planner.frozen_steps = 0
        planner.set_target(BALL)
        planner.last_report = report
        return planner

    make.initial_report = report
    return make
