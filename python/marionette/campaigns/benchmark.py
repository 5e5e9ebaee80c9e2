"""bench/campaigns: what running trials side by side buys, on this machine and on a Ray cluster.

The same campaign (default: 20 ur10-box trials, unpaced, each trial its own plan seed) is run
three ways through ``marionette demo``: serially (``--jobs 1``), ``--jobs 2``, and on a Ray
cluster of two 1-CPU worker nodes started on this machine (:mod:`.local_cluster`). For each: the
wall time, the success count, the mean trial time (from the campaign report) and the machine's
busy cores over the run (from /proc/stat). From them:

* the speed-up of each parallel run over the serial one, on execution: the planning of seeds not
  yet cached (done by whichever run comes first) is timed apart;
* the ceiling of that speed-up on this machine: a serial trial already keeps ``c`` cores busy
  (controller, simulator, supervisor, perception), so K jobs cannot go faster than
  ``min(K, cores / c)``;
* Ray's overhead per trial: its wall time beyond ``--jobs 2``'s, per trial, over the mean trial
  (the cluster's own start is timed apart);
* what N machines of this kind would take: trials / (N x slots) rounds of the mean trial, plus
  the overhead.

  python -m marionette.campaigns.benchmark [--scenario NAME] [--trials N] [--only serial,jobs2,ray]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from marionette.campaigns.local_cluster import local_cluster


def _cpu_jiffies() -> tuple[int, int]:
    """(busy, total) jiffies of all CPUs since boot."""
    fields = [int(x) for x in Path("/proc/stat").read_text().splitlines()[0].split()[1:]]
    idle = fields[3] + fields[4]  # idle + iowait
    return sum(fields) - idle, sum(fields)


def _campaign(scenario: str, trials: int, out: Path, extra: list[str], log=print) -> dict:
    """Runs one campaign through the CLI; its wall time, busy cores and report."""
    argv = [sys.executable, "-m", "marionette.cli", "demo", scenario, "--trials", str(trials)]
    argv += ["--speed", "0", "--out", str(out), *extra]
    log("  $ marionette " + " ".join(argv[3:]))
    busy0, total0 = _cpu_jiffies()
    t0 = time.monotonic()
    done = subprocess.run(argv, capture_output=True, text=True)
    wall = time.monotonic() - t0
    busy1, total1 = _cpu_jiffies()
    reports = sorted(out.glob("*campaign*/report.json"))
    if not reports:
        raise RuntimeError(
            f"no campaign report under {out} (exit {done.returncode}):\n{done.stderr[-2000:]}"
        )
    report = json.loads(reports[-1].read_text())
    trial_wall = [t["wall_s"] for t in report["trials"] if t.get("wall_s") is not None]
    # Planning is cached across runs: the first run plans the seeds not cached yet, the others
    # do not. Its time is reported apart so that the runs compare on execution.
    planning = 0.0
    for t in report["trials"]:
        trial_report = (reports[-1].parent / str(t.get("report") or "")).with_suffix(".json")
        if t.get("report") and trial_report.is_file():
            planning += json.loads(trial_report.read_text()).get("timings", {}).get("plan_s", 0.0)
    return {
        "argv": ["marionette", *argv[3:]],
        "exit_code": done.returncode,
        "wall_s": wall,
        "planning_s": planning,
        "succeeded": report["counts"]["succeeded"],
        "trials": len(report["trials"]),
        "engine": report["campaign"]["engine"],
        "mean_trial_s": sum(trial_wall) / len(trial_wall) if trial_wall else math.nan,
        "busy_cores": (os.cpu_count() or 1) * (busy1 - busy0) / max(total1 - total0, 1),
        "failure_groups": report.get("failure_groups"),
        "criteria": {
            name: {k: c.get(k) for k in ("unit", "median", "p90", "max")}
            for name, c in (report.get("criteria") or {}).items()
        },
    }


def run(scenario: str, trials: int, only: set[str], log=print) -> dict:
    cores = os.cpu_count() or 1
    results: dict = {"scenario": scenario, "trials": trials, "cores": cores}
    results["load_average_before"] = os.getloadavg()
    # Kept: each run's campaign report links its trials' reports.
    root = Path(tempfile.mkdtemp(prefix="bench-campaigns-"))
    results["folder"] = str(root)
    log(f"campaign reports under {root}")
    if "serial" in only:
        log("serial")
        results["serial"] = _campaign(scenario, trials, root / "serial", ["--jobs", "1"], log)
    if "jobs2" in only:
        log("--jobs 2")
        results["jobs2"] = _campaign(scenario, trials, root / "jobs2", ["--jobs", "2"], log)
    if "ray" in only:
        log("Ray: a head and two 1-CPU workers on 127.0.0.1")
        t0 = time.monotonic()
        with local_cluster(workers=2, cpus_per_worker=1, log_dir=root / "ray-logs") as cluster:
            results["ray_cluster_start_s"] = time.monotonic() - t0
            results["ray"] = _campaign(
                scenario, trials, root / "ray", ["--cluster", cluster.address], log
            )
    _derive(results)
    return results


def _derive(r: dict) -> None:
    serial = r.get("serial")
    if serial is None:
        return
    per_trial = serial["mean_trial_s"]
    r["ceiling_speedup_2_slots"] = min(2.0, r["cores"] / max(serial["busy_cores"], 1e-9))

    def executing(run: dict) -> float:  # wall time without the planning of uncached seeds
        return run["wall_s"] - run["planning_s"]

    for name in ("jobs2", "ray"):
        if name in r:
            r[name]["speedup"] = executing(serial) / executing(r[name])
    if "jobs2" in r and "ray" in r:
        overhead = (executing(r["ray"]) - executing(r["jobs2"])) * 2 / r["trials"]
        r["ray_overhead_per_trial_s"] = overhead
        r["ray_overhead_fraction"] = overhead / per_trial
    slots = 2
    extra = max(r.get("ray_overhead_per_trial_s", 0.0), 0.0)
    r["extrapolated_wall_s"] = {
        str(n): math.ceil(r["trials"] / (n * slots)) * (per_trial + extra)
        for n in (1, 2, 5, 10, 50)
    }


def _print(r: dict) -> None:
    print(f"\n{r['trials']} {r['scenario']} trials, unpaced, on {r['cores']} cores")
    header = (
        ("wall [s]", 10),
        ("planning [s]", 14),
        ("ok", 6),
        ("mean trial [s]", 16),
        ("busy cores", 12),
        ("speed-up", 10),
    )
    print(f"{'run':<10}" + "".join(f"{h:>{w}}" for h, w in header))
    for name in ("serial", "jobs2", "ray"):
        if name in r:
            x = r[name]
            print(
                f"{name:<10}{x['wall_s']:>10.1f}{x['planning_s']:>14.1f}{x['succeeded']!s:>6}"
                f"{x['mean_trial_s']:>16.1f}"
                f"{x['busy_cores']:>12.2f}{x.get('speedup', 1.0):>10.2f}"
            )
    if "ceiling_speedup_2_slots" in r:
        print(
            f"ceiling for 2 slots on this machine: {r['ceiling_speedup_2_slots']:.2f}x (a serial "
            f"trial keeps {r['serial']['busy_cores']:.2f} of {r['cores']} cores busy)"
        )
    if "ray_overhead_per_trial_s" in r:
        print(
            f"Ray: cluster start {r['ray_cluster_start_s']:.1f} s (once), overhead per trial "
            f"{r['ray_overhead_per_trial_s']:.2f} s = "
            f"{100 * r['ray_overhead_fraction']:.1f} % of a trial"
        )
    if "extrapolated_wall_s" in r:
        rows = ", ".join(
            f"{n} machine{'s' if n != '1' else ''} {s / 60:.1f} min"
            for n, s in r["extrapolated_wall_s"].items()
        )
        print(f"extrapolated (2 slots per machine, this machine's trial time): {rows}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(
        prog="bench/campaigns", description=__doc__, formatter_class=argparse.RawTextHelpFormatter
    )
    p.add_argument("--scenario", default="ur10-box")
    p.add_argument("--trials", type=int, default=20)
    p.add_argument("--only", default="serial,jobs2,ray", help="runs among serial,jobs2,ray")
    p.add_argument("--out", type=Path, default=Path("reports/bench/campaigns.json"))
    args = p.parse_args(argv)
    only = set(args.only.split(","))
    unknown = only - {"serial", "jobs2", "ray"}
    if unknown:
        p.error(f"unknown run(s) {sorted(unknown)}: choose among serial, jobs2, ray")
    results = run(args.scenario, args.trials, only)
    _print(results)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(results, indent=1))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
