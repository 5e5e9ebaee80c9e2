"""``marionette dg ...``: the running controller's graph from the command line (any machine on
the LCM network): ls, get, set, trace, graph, timing, budget; and status (mode, refused inputs per
channel and reason)."""

from __future__ import annotations

import argparse
import csv
import sys

import numpy as np

from marionette.control.introspection import (
    GraphClient,
    IntrospectionError,
    read_status,
    status_text,
)


def register(sub: argparse._SubParsersAction) -> None:
    dg = sub.add_parser(
        "dg",
        help="inspect and tune the running controller's graph",
        epilog=(
            "examples:\n"
            "  marionette dg ls\n"
            "  marionette dg get c1_posture.gain command.configuration\n"
            "  marionette dg set c1_posture.gain 3.5\n"
            "  marionette dg trace c1_solver.velocity --rate 1000 --duration 5 --out v.csv"
        ),
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    dg.add_argument("--lcm-url", default=None, help="default: $MARIONETTE_LCM_URL")
    dg.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for a reply")
    cmds = dg.add_subparsers(dest="dg_command", required=True, metavar="DG_COMMAND")
    cmds.add_parser("ls", help="entities, their signals, plugs and settable inputs")
    p = cmds.add_parser("get", help="current value of signals")
    p.add_argument("signals", nargs="+", metavar="ENTITY.SIGNAL")
    p = cmds.add_parser("set", help="set an input declared settable (e.g. a gain)")
    p.add_argument("signal", metavar="ENTITY.SIGNAL")
    p.add_argument("value", nargs="+", type=float, help="the value, flattened column-major")
    p = cmds.add_parser("trace", help="stream signals to a CSV file")
    p.add_argument("signals", nargs="+", metavar="ENTITY.SIGNAL")
    p.add_argument("--rate", type=float, default=100.0, help="samples per second (<= 1000)")
    p.add_argument("--duration", type=float, default=5.0, help="seconds")
    p.add_argument("--out", default="trace.csv")
    p.add_argument("--plot", default=None, metavar="PNG", help="also plot the trace")
    p = cmds.add_parser("graph", help="the running graph in Graphviz dot")
    p.add_argument("--dot", action="store_true", help="print dot (the default)")
    p.add_argument("--png", default=None, help="render to this PNG with Graphviz")
    cmds.add_parser("timing", help="per-entity compute time (p50, p99, max), budgets, overruns")
    cmds.add_parser(
        "status", help="mode and why, active controller, refused inputs per channel and reason"
    )
    p = cmds.add_parser("budget", help="declare an entity's compute-time budget per tick")
    p.add_argument("entity")
    p.add_argument("budget_us", type=float, help="microseconds, 0 removes the budget")
    dg.set_defaults(func=_run)


def _format(name: str, value: np.ndarray) -> str:
    if value.ndim == 0:
        return f"{name} = {float(value):.9g}"
    text = np.array2string(value, precision=6, suppress_small=True, max_line_width=120)
    return f"{name} {value.shape} =\n{text}"


def _run(args: argparse.Namespace) -> int:
    if args.dg_command == "status":  # CONTROLLER_STATUS: no request to the controller
        try:
            print(status_text(read_status(args.lcm_url, args.timeout)), end="")
        except IntrospectionError as exc:
            print(f"marionette dg: {exc}", file=sys.stderr)
            return 1
        return 0
    try:
        with GraphClient(args.lcm_url, timeout_s=args.timeout) as client:
            if args.dg_command == "ls":
                print(client.ls(), end="")
            elif args.dg_command == "get":
                tick, values = client.get_with_tick(*args.signals)
                print(f"# tick {tick}")
                for name in args.signals:
                    print(_format(name, values[name]))
            elif args.dg_command == "set":
                client.set(args.signal, args.value)
                print(f"{args.signal} set")
            elif args.dg_command == "graph":
                dot = client.dot()
                if args.png:
                    import subprocess

                    subprocess.run(["dot", "-Tpng", "-o", args.png], input=dot.encode(), check=True)
                    print(f"wrote {args.png}")
                else:
                    print(dot, end="")
            elif args.dg_command == "timing":
                print(client.timing(), end="")
            elif args.dg_command == "budget":
                print(client.budget(args.entity, args.budget_us))
            elif args.dg_command == "trace":
                return _trace(client, args)
    except IntrospectionError as exc:
        print(f"marionette dg: {exc}", file=sys.stderr)
        return 1
    return 0


def _trace(client: GraphClient, args: argparse.Namespace) -> int:
    rows: list[list[float]] = []
    header: list[str] = []  # set with the first sample
    for sample in client.trace(args.signals, args.rate, args.duration):
        if not header:
            header = ["tick", "time"]
            for name in args.signals:
                size = sample.values[name].size
                header += [f"{name}[{i}]" for i in range(size)] if size > 1 else [name]
        row = [sample.tick, sample.utime * 1e-6]
        for name in args.signals:
            row += list(np.asarray(sample.values[name]).flatten(order="F"))
        rows.append(row)
    if not rows:
        print("marionette dg: no sample received", file=sys.stderr)
        return 1
    with open(args.out, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(rows)
    print(f"wrote {len(rows)} samples of {len(args.signals)} signals to {args.out}")
    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        data = np.array(rows)
        fig, ax = plt.subplots(figsize=(9, 4))
        for j, name in enumerate(header[2:], start=2):
            ax.plot(data[:, 1], data[:, j], label=name)
        ax.set_xlabel("controller time [s]")
        ax.set_ylabel("signal value [each signal's unit]")
        ax.grid(True, alpha=0.3)
        if len(header) <= 14:
            ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(args.plot, dpi=120)
        print(f"wrote {args.plot}")
    return 0
