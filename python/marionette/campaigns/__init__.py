"""Trial campaigns: many trials of one scenario, on this machine (``--jobs K``) or on a Ray
cluster (``--cluster ADDRESS``), gathered in one folder with one report (``docs/scenarios.md``).

| module | job |
|---|---|
| `trial.py` | one trial: its `marionette demo` child process, what it left, its files packed |
| `backend.py` | what a campaign asks of the engine that runs its trials |
| `local.py` | `--jobs K`: K trial processes at once on this machine |
| `ray_cluster.py` | `--cluster ADDRESS`: each trial a Ray task on a worker, its files returned |
| `campaign.py` | the campaign folder, resume, progress, the trials' rows |
| `report.py` | the campaign report: success rate, failures, criteria, worst and slowest trials |
| `stats.py` | the Wilson interval, summaries |
| `errors.py` | `CampaignError` |
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from marionette.campaigns.campaign import Campaign, CampaignSettings
from marionette.campaigns.errors import CampaignError
from marionette.scenarios.base import Scenario


def run_campaign(
    folder: Path,
    settings: CampaignSettings,
    scenario: Scenario,
    jobs: int = 1,
    cluster: str | None = None,
    retries: int = 1,
    log: Callable[[str], None] = print,
) -> dict[str, Any]:
    """Runs (or resumes) the campaign in ``folder`` with ``jobs`` trials at once on this
    machine, or on the Ray cluster at ``cluster``; returns the campaign report."""
    from marionette.campaigns.backend import Backend

    backend: Backend
    if cluster:
        from marionette.campaigns.ray_cluster import RayCluster

        backend = RayCluster(cluster, retries)
    else:
        from marionette.campaigns.local import LocalPool

        backend = LocalPool(jobs)
    return Campaign(folder, settings, scenario, log).run(backend)


__all__ = ["Campaign", "CampaignError", "CampaignSettings", "run_campaign"]
