"""marionette: plan manipulation and walking with a constraint graph, execute it at 1 kHz.

The compiled parts (the extension ``marionette._core`` and the generated LCM types) are built by
CMake into ``<build>/python/marionette``; that directory is appended to this package's path so
both import from ``marionette``: ``from marionette import lcmt_robot_state`` gives the type.
"""

import os as _os
from pathlib import Path as _Path

REPO_ROOT = _Path(__file__).resolve().parents[2]
BUILD_DIR = _Path(_os.environ.get("MARIONETTE_BUILD_DIR", REPO_ROOT / "build")).resolve()
MODELS_DIR = REPO_ROOT / "models"

_compiled = BUILD_DIR / "python" / "marionette"
if _compiled.is_dir():
    __path__.append(str(_compiled))
    # As lcm-gen's own package __init__ does: ``marionette.lcmt_x`` is the class, which the
    # generated code of nested types relies on (``marionette.lcmt_task_spec._get_hash_recursive``).
    import importlib as _importlib

    for _type_file in sorted(_compiled.glob("lcmt_*.py")):
        _name = _type_file.stem
        globals()[_name] = getattr(_importlib.import_module(f"{__name__}.{_name}"), _name)

__version__ = "0.1.0"


def __getattr__(name: str):  # the generated types and extensions, when the build is missing
    raise AttributeError(
        f"module 'marionette' has no attribute {name!r}"
        + (
            f" (no C++ build in {BUILD_DIR}: run `make` or scripts/setup)"
            if not _compiled.is_dir()
            else ""
        )
    )
