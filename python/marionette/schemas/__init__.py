"""Data files validated against their published JSON Schemas (the ``*.schema.json`` beside this
file): one function, :func:`load_validated`, and one error, :class:`DataFileError`, whose message
is one line that names the file, the line, the key and what to do.

    robot.yaml                    robot.schema.json      (docs/robots.md)
    models/scenes/<scene>.yaml    scene.schema.json      (docs/robots.md)
    scenario declarations         scenario.schema.json   (docs/scenarios.md)
    trial perturbations           perturbation.schema.json (docs/scenarios.md)
    planning problem files        problem.schema.json    (python/marionette/planning/README.md)

A YAML syntax error, an unknown key (with the closest known one: "did you mean"), a wrong type or
a value out of range are all refused the same way, before anything reads the data.
"""

from __future__ import annotations

import difflib
import functools
import json
from pathlib import Path
from typing import Any

import jsonschema
import yaml

SCHEMAS_DIR = Path(__file__).resolve().parent

__all__ = [
    "SCHEMAS_DIR",
    "DataFileError",
    "load_validated",
    "problems",
    "read_yaml",
    "schema",
    "validate",
]


class DataFileError(ValueError):
    """A data file is missing, not YAML, or does not follow its schema (one-line message)."""


@functools.cache
def schema(name: str) -> dict[str, Any]:
    """The JSON Schema ``<name>.schema.json`` of this folder."""
    return json.loads((SCHEMAS_DIR / f"{name}.schema.json").read_text())


@functools.cache
def _validator(name: str) -> jsonschema.protocols.Validator:
    s = schema(name)
    cls = jsonschema.validators.validator_for(s)
    cls.check_schema(s)
    return cls(s)


def read_yaml(path: str | Path) -> Any:
    """The parsed YAML of ``path``; raises :class:`DataFileError` with one line,
    ``path[:line]: problem``, when it is missing, unreadable or not YAML. Every data file of the
    project is read by this function (or by :func:`load_validated`, which also checks it)."""
    return _parse(path, with_nodes=False)[0]


def load_validated(path: str | Path, schema_name: str) -> dict[str, Any]:
    """The YAML mapping of ``path``, checked against schema ``schema_name``; raises
    :class:`DataFileError` with ``path:line: key: problem`` otherwise."""
    data, node = _parse(path, with_nodes=True)
    validate(data, schema_name, str(path), node)
    return data


def _parse(path: str | Path, with_nodes: bool) -> tuple[Any, yaml.Node | None]:
    """The data of ``path`` and, ``with_nodes``, its node tree (the line of a key: a second
    parse, done only for the files checked against a schema)."""
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise DataFileError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise DataFileError(f"{path}: is a folder, not a file") from None
    except (OSError, UnicodeDecodeError) as e:
        reason = e.strerror if isinstance(e, OSError) else "not text"
        raise DataFileError(f"{path}: cannot read it ({reason})") from None
    try:
        data = yaml.safe_load(text)
        return data, yaml.compose(text, Loader=yaml.SafeLoader) if with_nodes else None
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        where = f"{path}:{mark.line + 1}" if mark is not None else str(path)
        raise DataFileError(f"{where}: not valid YAML: {e.problem or e.context}") from None
    except yaml.YAMLError as e:
        raise DataFileError(f"{path}: not valid YAML: {str(e).splitlines()[0]}") from None


def problems(data: Any, schema_name: str) -> list[str]:
    """Every way ``data`` breaks schema ``schema_name``, one line each, ``where: what``, ordered
    by place; an unknown key with the closest known one ("did you mean"), else the known keys."""
    out = []
    for e in sorted(
        _validator(schema_name).iter_errors(data), key=lambda e: list(map(str, e.absolute_path))
    ):
        where = _where(e.absolute_path)
        if e.validator == "additionalProperties" and isinstance(e.instance, dict):
            known = sorted((e.schema.get("properties") or {}).keys())
            for key in sorted(set(e.instance) - set(known), key=str):
                close = difflib.get_close_matches(str(key), known, n=1, cutoff=0.6)
                hint = f"did you mean {close[0]!r}?" if close else f"known keys: {', '.join(known)}"
                out.append(f"{where}: unknown key {key!r}; {hint}")
        else:
            out.append(f"{where}: {e.message}")
    return out


def validate(data: Any, schema_name: str, source: str = "<data>", node: Any = None) -> None:
    """Raises :class:`DataFileError` naming the first problem of ``data`` against schema
    ``schema_name`` (with its line when ``node``, ``yaml.compose`` of the same text, is given)."""
    errors = sorted(_validator(schema_name).iter_errors(data), key=_error_rank)
    if not errors:
        return
    first = errors[0]
    line = _line_of(node, list(first.absolute_path))
    where = f"{source}:{line}" if line else source
    message = next(
        p for p in problems(data, schema_name) if p.startswith(_where(first.absolute_path))
    )
    raise DataFileError(f"{where}: {message}")


def _where(path) -> str:
    return "/".join(str(p) for p in path) or "(top level)"


def _error_rank(e: jsonschema.ValidationError) -> tuple[int, int]:
    # Unknown and missing keys first (typos), then the deepest error (the most precise).
    kind = 0 if e.validator in ("additionalProperties", "required") else 1
    return (kind, -len(e.absolute_path))


def _line_of(node: Any, path: list[Any]) -> int | None:
    """1-based line of the YAML node at ``path`` (or of its deepest ancestor found)."""
    line = None
    for key in path:
        if node is None:
            break
        line = node.start_mark.line + 1
        if isinstance(node, yaml.MappingNode):
            node = next((v for k, v in node.value if k.value == str(key)), None)
            if node is None:
                break
            line = node.start_mark.line + 1
        elif isinstance(node, yaml.SequenceNode) and isinstance(key, int) and key < len(node.value):
            node = node.value[key]
            line = node.start_mark.line + 1
        else:
            break
    if line is None and node is not None:
        line = node.start_mark.line + 1
    return line
