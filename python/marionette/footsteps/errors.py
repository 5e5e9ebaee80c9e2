"""Exceptions of the footstep optimiser (one base class, as mink does per package)."""

from __future__ import annotations


class FootstepError(Exception):
    """Base class of every error raised by :mod:`marionette.footsteps`."""


class InvalidProblem(FootstepError, ValueError):
    """A constraint, task, limit or scene was given inconsistent or out-of-range values."""


class PlanningFailed(FootstepError, RuntimeError):
    """The optimiser could not satisfy the primary task within its step / iteration budget."""
