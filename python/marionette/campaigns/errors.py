"""Exceptions of the campaigns (one base class per package)."""

from __future__ import annotations


class CampaignError(RuntimeError):
    """A campaign cannot run: a bad option, a campaign folder of other settings, no cluster."""
