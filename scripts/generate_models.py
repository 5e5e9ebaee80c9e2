#!/usr/bin/env python3
"""Regenerate models/: the bundled robots' URDF/SRDF from example-robot-data, every robot's MJCF
from its URDF + robot.yaml, the bundled objects, every scene's MJCF, the tag textures.

    scripts/generate_models.py                 # rewrite the generated files in models/
    scripts/generate_models.py --out DIR       # write them elsewhere (e.g. to compare)
    scripts/generate_models.py --link-meshes   # only (re)create models/<robot>/meshes links

The generic logic lives in python/marionette/models; the bundled robots' URDF edits in
scripts/bundled_models.py (see models/README.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))
sys.path.insert(0, str(Path(__file__).resolve().parent))  # bundled_models

import marionette
from marionette.models import generate


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out",
        type=Path,
        default=marionette.MODELS_DIR,
        help="output directory (default: models/)",
    )
    parser.add_argument(
        "--link-meshes", action="store_true", help="only create the models/<robot>/meshes links"
    )
    args = parser.parse_args(argv)
    if args.link_meshes:
        for link in generate.link_meshes(args.out):
            print(f"{link} -> {link.resolve()}")
        return 0
    from bundled_models import SOURCES, derived_srdf, derived_urdf

    written = []
    for name in SOURCES:
        urdf = derived_urdf(name)
        for suffix, text in ((".urdf", urdf), (".srdf", derived_srdf(name, urdf))):
            path = args.out / name / f"{name}{suffix}"
            path.parent.mkdir(parents=True, exist_ok=True)
            if not path.exists() or path.read_text() != text:
                path.write_text(text)
            written.append(path)
    written += generate.write(args.out)
    generate.link_meshes(args.out)
    print(f"wrote {len(written)} files under {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
