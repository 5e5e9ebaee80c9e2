"""Strict validation of problem files against ``marionette/schemas/problem.schema.json`` (JSON
Schema, checked by the ``jsonschema`` library): one line per bad file, naming the key by its path.

An unknown key is refused with the nearest known key at that place ("did you mean"), a value of
the wrong type or range with the path of the key and what was expected.
"""

from __future__ import annotations

import difflib
from functools import cache
from typing import Any

import jsonschema

from marionette import schemas


def schema() -> dict[str, Any]:
    """The problem file schema (a dict)."""
    return schemas.schema("problem")


@cache
def _validator() -> jsonschema.protocols.Validator:
    cls = jsonschema.validators.validator_for(schema())
    cls.check_schema(schema())
    return cls(schema())


def _path(error: jsonschema.ValidationError) -> str:
    out = ""
    for part in error.absolute_path:
        out += f"[{part}]" if isinstance(part, int) else (f".{part}" if out else str(part))
    return out or "(top level)"


def _known_keys(error: jsonschema.ValidationError) -> list[str]:
    """Keys the schema at the error's place defines (through $ref / allOf as used here)."""
    keys: list[str] = []

    def collect(s: dict[str, Any]) -> None:
        if "$ref" in s:
            ref = s["$ref"]
            node = schema()
            for part in ref.lstrip("#/").split("/"):
                node = node[part]
            collect(node)
        keys.extend(s.get("properties", {}))

    collect(error.schema)
    return keys


def _unknown_key_message(error: jsonschema.ValidationError) -> str | None:
    if error.validator not in ("additionalProperties", "unevaluatedProperties"):
        return None
    instance = error.instance if isinstance(error.instance, dict) else {}
    known = _known_keys(error)
    unknown = [k for k in instance if k not in known]
    if not unknown:
        return None
    key = unknown[0]
    where = _path(error)
    close = difflib.get_close_matches(str(key), known, n=1)
    hint = f"; did you mean '{close[0]}'?" if close else f" (known: {', '.join(sorted(known))})"
    place = "" if where == "(top level)" else f" in {where}"
    return f"unknown key '{key}'{place}{hint}"


def _best(errors: list[jsonschema.ValidationError]) -> jsonschema.ValidationError:
    best = jsonschema.exceptions.best_match(errors)
    # Inside oneOf / anyOf, the deepest error names the key that is wrong.
    while best.context:
        best = jsonschema.exceptions.best_match(best.context)
    return best


def _alternatives_message(error: jsonschema.ValidationError) -> str | None:
    """A mapping that fits none of a oneOf / anyOf's alternatives because of a key none of
    them knows: that key, with the nearest known one."""
    if error.validator not in ("oneOf", "anyOf") or not isinstance(error.instance, dict):
        return None
    known: list[str] = []
    for branch in error.validator_value:
        known += _known_keys(jsonschema.ValidationError("", schema=branch))
    unknown = [k for k in error.instance if k not in known]
    if not unknown or not known:
        return None
    close = difflib.get_close_matches(str(unknown[0]), known, n=1)
    hint = (
        f"; did you mean '{close[0]}'?" if close else f" (known: {', '.join(sorted(set(known)))})"
    )
    return f"unknown key '{unknown[0]}' in {_path(error)}{hint}"


def _described(error: jsonschema.ValidationError) -> str | None:
    """The description of the schema a oneOf / anyOf error is about (what was expected)."""
    if error.validator not in ("oneOf", "anyOf"):
        return None
    return error.schema.get("description")


def problem_errors(doc: Any) -> list[str]:
    """Every schema violation of a parsed problem file, one line each (empty when valid)."""
    errors = list(_validator().iter_errors(doc))
    out = []
    for e in sorted(errors, key=lambda e: list(map(str, e.absolute_path))):
        leaf = _best([e])
        msg = _alternatives_message(e) or _unknown_key_message(leaf) or _unknown_key_message(e)
        if msg is None:
            described = _described(e)
            same_place = list(leaf.absolute_path) == list(e.absolute_path)
            if described is not None and leaf is not e and same_place:
                msg = f"{_path(e)}: {e.instance!r} is not {described}"
            else:
                msg = f"{_path(leaf)}: {leaf.message}"
        out.append(msg)
    return out


def validate_problem(doc: Any) -> str | None:
    """The first schema violation of a parsed problem file as one line, or None."""
    errors = problem_errors(doc)
    return errors[0] if errors else None
