#!/usr/bin/env python3
"""Regenerate models/ (robots, objects, scenes, tag textures) from example-robot-data.

    scripts/generate_models.py                 # rewrite the committed files in models/
    scripts/generate_models.py --out DIR       # write them elsewhere (e.g. to compare)
    scripts/generate_models.py --link-meshes   # only (re)create models/<robot>/meshes links

The logic lives in python/marionette/models (see models/README.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "python"))

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
    written = generate.write(args.out)
    generate.link_meshes(args.out)
    print(f"wrote {len(written)} files under {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
