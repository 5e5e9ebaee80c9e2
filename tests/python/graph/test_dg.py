"""The dynamic graph driven from Python: build, set inputs from numpy, run in C++, read back."""

from __future__ import annotations

import numpy as np
import pytest

from marionette import dg


def _damped_system(x0):
    """x' = -k x with k a settable gain: x_n = (1 - k dt)^n x0 (explicit Euler)."""
    b = dg.GraphBuilder()
    x = b.add(dg.VectorIntegrator("x", np.asarray(x0, dtype=float)))
    k = b.add(dg.VectorGain("k", len(x0), -2.0))
    b.connect(x.output("state"), k.input("in"))
    b.connect("k.out", "x.derivative")
    tracer = b.add(dg.Tracer("tracer", 100, [x.output("state")]))
    return b.build(), x, k, tracer


def test_graph_runs_in_cpp_and_matches_closed_form():
    graph, x, _k, tracer = _damped_system([1.0, -3.0])
    tick = dg.Tick(dt=1e-3)
    graph.run(tick, 500)
    assert tick.index == 500
    np.testing.assert_allclose(x.output("state").value, (1 - 2e-3) ** 500 * np.array([1.0, -3.0]))
    rows = tracer.rows()
    assert rows.shape == (100, 4)
    assert tracer.column_names == ["tick", "time", "x.state[0]", "x.state[1]"]
    np.testing.assert_allclose(rows[-1, 2:], (1 - 2e-3) ** 499 * np.array([1.0, -3.0]))


def test_fixed_inputs_from_numpy_and_shape_errors():
    graph, x, k, _ = _damped_system([1.0, 1.0])
    k.input("gain").set_value(0.0)  # settable parameter: x' = 0
    tick = dg.Tick()
    graph.run(tick, 10)
    np.testing.assert_allclose(x.output("state").value, [1.0, 1.0])
    assert k.input("gain").settable
    c = dg.VectorConstant("c", np.zeros(3))
    with pytest.raises(dg.GraphError, match=r"c\.value: 2 values given, 3 expected"):
        c.input("value").set_value(np.ones(2))


def test_matrix_inputs_and_outputs_round_trip():
    b = dg.GraphBuilder()
    p = b.add(dg.MatrixVectorProduct("p", 2, 3))
    m = np.arange(6.0).reshape(2, 3)
    p.input("matrix").set_value(m)
    p.input("vector").set_value(np.array([1.0, 0.5, -1.0]))
    b.add(dg.Tracer("t", 1, [p.output("out")]))
    graph = b.build()
    graph.run(dg.Tick(), 1)
    np.testing.assert_allclose(graph.signal("p.matrix").value, m)
    np.testing.assert_allclose(p.output("out").value, m @ [1.0, 0.5, -1.0])


def test_builder_errors_reach_python_with_names():
    b = dg.GraphBuilder()
    b.add(dg.VectorGain("g", 3, 1.0))
    b.add(dg.VectorConstant("c", np.zeros(2)))
    with pytest.raises(dg.GraphError, match=r"shape mismatch.*c\.out.*g\.in"):
        b.connect("c.out", "g.in")
    with pytest.raises(dg.GraphError, match=r"g\.in .*neither plugged nor set"):
        b.build()


def test_introspection_and_dot():
    graph, _x, _k, _ = _damped_system([0.0])
    names = sorted(e.name for e in graph.entities)
    assert names == ["k", "tracer", "x"]
    assert graph.signal("x.derivative").source == "k.out"
    assert graph.signal("x.state").kind == "state"
    assert [s.name for s in graph.entity("k").inputs] == ["in", "gain"]
    dot = graph.to_dot()
    assert '"k":"out":e -> "x":"derivative":w' in dot
    with pytest.raises(dg.GraphError, match="entities: "):
        graph.entity("nobody")


def test_edit_swaps_an_entity_between_ticks():
    graph, x, _k, _ = _damped_system([1.0])
    tick = dg.Tick()
    graph.run(tick, 10)
    edit = dg.GraphEdit(graph)
    edit.add(dg.VectorGain("k2", 1, 0.0))
    edit.connect("x.state", "k2.in")
    edit.connect("k2.out", "x.derivative")
    edit.remove("k")
    edit.prepare()
    assert graph.apply(edit)
    before = x.output("state").value.copy()
    graph.run(tick, 10)
    np.testing.assert_allclose(x.output("state").value, before)  # x' = 0 now
    assert graph.version == 2
