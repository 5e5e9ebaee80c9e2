"""Certified continuous collision checking against dense sampling (brute force)."""

from __future__ import annotations

import numpy as np
import pytest

from marionette.planning.collision import CollisionChecker
from marionette.planning.graph_factory import graph_from_settings
from marionette.planning.problem import random_configuration


def dense_first_collision(checker, path, step=5e-4):
    """Arc length of the first colliding sample every `step`, or None."""
    n = int(np.ceil(path.length / step)) + 1
    for s in np.linspace(0.0, path.length, n):
        if not checker.is_valid(path.eval(s)):
            return s
    return None


@pytest.mark.slow
def test_certified_validation_agrees_with_dense_sampling(ur5_box):
    """Over transit paths of the UR5 (box still on the table): whenever the certified check
    accepts a path, dense sampling finds no collision; when it stops at s, the path is free
    up to s (brute force) and collides shortly after."""
    p = ur5_box
    g = graph_from_settings(p)
    edge = g.edges["Loop | f"]
    checker = CollisionChecker(p)
    rng = np.random.default_rng(11)
    accepted = rejected = 0
    while accepted < 6 or rejected < 6:
        qa, qb = p.q_init.copy(), p.q_init.copy()
        qa[:6] = random_configuration(p, rng)[:6]
        qb[:6] = random_configuration(p, rng)[:6]
        if not (checker.is_valid(qa) and checker.is_valid(qb)):
            continue
        paths = edge.build(qa, qb)
        assert paths is not None
        path = paths[0]
        ok, s_valid = checker.validate(path)
        brute = dense_first_collision(checker, path)
        if ok:
            assert brute is None
            accepted += 1
        else:
            assert brute is not None and brute >= s_valid - 1e-9
            # The certificate is conservative but not absurdly so: the collision found by
            # brute force is within 30 % of the path length after s_valid.
            assert brute - s_valid < 0.3 * path.length
            rejected += 1


def test_grasped_box_moves_with_the_gripper_and_is_checked(ur5_box):
    """A transfer path (box rigidly held) through the table is rejected; the pairs between the
    box and the wrist are rigid in that transition and only checked once."""
    p = ur5_box
    g = graph_from_settings(p)
    edge = g.edges["Loop | 0-0"]
    checker = CollisionChecker(p)
    rigid, R, _L, _ = checker._motion(edge.path_projector)
    names = [o.name for o in checker.geom_model.geometryObjects]
    pair_names = [(names[a], names[b]) for a, b in checker.pairs]
    k = pair_names.index(("ur5/tool0_0", "box/base_link_0"))
    assert rigid[k]
    kt = pair_names.index(("box/base_link_0", "table/base_link_0"))
    assert not rigid[kt] and R[kt].sum() > 0
    # From a free grasp configuration to one where the held box is inside the table.
    s = g.states["ur5/gripper grasps box/handle"]
    qa = p.q_init.copy()
    s.project(qa)
    assert checker.is_valid(qa)
    rng = np.random.default_rng(5)
    while True:
        qb = random_configuration(p, rng)
        s.project(qb)
        if ("box/base_link_0", "table/base_link_0") in checker.colliding_pairs(qb):
            break
    path = edge.build(qa, qb)[0]
    ok, s_valid = checker.validate(path)
    assert not ok
    assert dense_first_collision(checker, path) >= s_valid - 1e-9
