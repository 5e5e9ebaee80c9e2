"""Side-by-side run of marionette and HPP on one problem (entry point of bench/ur5_box_vs_hpp).

Seeds are run in alternating blocks (HPP block, marionette block, ...) so that both systems see
the same machine load; HPP runs in its own interpreter (``--hpp-python``) from
``--hpp-script``, which writes JSON in the format of :func:`benchmark.run_marionette`.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import tempfile
from pathlib import Path

from marionette.planning import benchmark


def _hpp_block(args: argparse.Namespace, first: int, last: int, samples: int) -> dict:
    env = dict(os.environ)
    env["LD_LIBRARY_PATH"] = f"{args.hpp_prefix}/lib:" + env.get("LD_LIBRARY_PATH", "")
    env["ROS_PACKAGE_PATH"] = f"{args.hpp_prefix}/share"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "hpp.json"
        subprocess.run(
            [
                args.hpp_python,
                args.hpp_script,
                "--seeds",
                str(first),
                str(last),
                "--projection-samples",
                str(samples),
                "--out",
                str(out),
            ],
            env=env,
            check=True,
            timeout=3600,
        )
        return json.loads(out.read_text())


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--seeds", type=int, default=50)
    ap.add_argument("--block", type=int, default=10, help="seeds per alternating block")
    ap.add_argument("--projection-samples", type=int, default=200)
    ap.add_argument("--problem", type=Path, required=True)
    ap.add_argument("--hpp-python", required=True)
    ap.add_argument("--hpp-prefix", required=True)
    ap.add_argument("--hpp-script", required=True)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args(argv)
    if args.seeds < 1:
        ap.error("--seeds must be >= 1")

    problem = benchmark.load_problem(args.problem)
    hpp_runs, mar_runs = [], []
    hpp_proj = mar_proj = {}
    # HPP seeds start at 1 (its seeds 0 and 1 behave alike, ../shared/bench/ur5_box/README.md).
    seeds = list(range(1, args.seeds + 1))
    for k in range(0, len(seeds), args.block):
        block = seeds[k : k + args.block]
        last_block = k + args.block >= len(seeds)
        samples = args.projection_samples if last_block else 1
        h = _hpp_block(args, block[0], block[-1], samples)
        hpp_runs += h["runs"]
        if last_block:
            hpp_proj = h["projections"]
        mar_runs += [vars(r) for r in benchmark.plan_seeds(problem, block)]
        print(
            f"  seeds {block[0]}-{block[-1]}: HPP {benchmark.summary(h['runs'])['median_ms']:.1f} ms, "
            f"marionette {benchmark.summary(mar_runs[-len(block) :])['median_ms']:.1f} ms (block medians)",
            flush=True,
        )
    mar_proj = benchmark.projection_times(problem, args.projection_samples)
    hs, ms = benchmark.summary(hpp_runs), benchmark.summary(mar_runs)

    print(f"\n{problem.name}, {len(seeds)} seeds, same machine, alternating blocks")
    print(f"{'':28s}{'HPP 9.0.2':>14s}{'marionette':>14s}{'ratio m/H':>11s}")
    for key, label, fmt in [
        ("success_rate", "success rate", "{:.0%}"),
        ("median_ms", "median planning time [ms]", "{:.1f}"),
        ("p90_ms", "p90 planning time [ms]", "{:.1f}"),
        ("median_nodes", "median roadmap nodes", "{:.0f}"),
    ]:
        ratio = ms[key] / hs[key] if hs[key] else float("nan")
        print(f"{label:28s}{fmt.format(hs[key]):>14s}{fmt.format(ms[key]):>14s}{ratio:>11.2f}")
    print("\nprojection of uniform samples onto each state: median time [us] (success rate)")
    for name in sorted(set(hpp_proj) | set(mar_proj)):
        h, m = hpp_proj.get(name), mar_proj.get(name)
        hs_ = f"{h['median_us']:.1f} ({h['success']:.0%})" if h else "-"
        ms_ = f"{m['median_us']:.1f} ({m['success']:.0%})" if m else "-"
        print(f"  {name:42s}{hs_:>16s}{ms_:>16s}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(
        json.dumps(
            {
                "hpp": {"summary": hs, "runs": hpp_runs, "projections": hpp_proj},
                "marionette": {"summary": ms, "runs": mar_runs, "projections": mar_proj},
            },
            indent=1,
        )
    )
    print(f"\nwritten {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
