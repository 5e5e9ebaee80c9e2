"""The dynamic graph from Python: build a graph of C++ entities, run it, read its signals.

    from marionette import dg
    b = dg.GraphBuilder()
    x = b.add(dg.VectorIntegrator("x", np.zeros(2)))
    k = b.add(dg.VectorGain("k", 2, -1.0))
    b.connect(x.output("state"), k.input("in"))
    b.connect("k.out", "x.derivative")
    graph = b.build()
    tick = dg.Tick(dt=1e-3)
    graph.run(tick, 1000)                  # evaluated in C++
    x.output("state").value                # numpy

Entities are created from their Python classes; signals are addressed as ``entity.signal``.
"""

from marionette._core.dg import (  # noqa: F401  (re-exported API)
    Entity,
    Graph,
    GraphBuilder,
    GraphEdit,
    GraphError,
    InputSignal,
    MatrixVectorProduct,
    Signal,
    Tick,
    Tracer,
    VectorConstant,
    VectorGain,
    VectorIntegrator,
    VectorSum,
)


def write_dot_png(graph: Graph, path: str) -> None:
    """Renders ``graph.to_dot()`` to a PNG with Graphviz's ``dot`` (installed by the set-up)."""
    import subprocess

    subprocess.run(["dot", "-Tpng", "-o", path], input=graph.to_dot().encode(), check=True)
