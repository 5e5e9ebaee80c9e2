"""The shared plans (tests/python/planned_fixtures.py)."""

from planned_fixtures import plan_cache, talos_plank, ur10_box  # noqa: F401
