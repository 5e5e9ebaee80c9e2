"""The exception of the execution runtime (one base class per package)."""

from __future__ import annotations


class ExecutionError(RuntimeError):
    """Execution cannot go on: the controller stopped tracking, a frame a task needs is missing."""
