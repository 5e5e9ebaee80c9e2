"""The schema of marionette's LCM types: ``lcmtypes/*.lcm`` read with the bounds annotated on
their fields (the grammar is in lcmtypes/README.md).

One reader for everything that needs the schema: the build generates the C++ and Python
validators' tables from it (scripts/generate_lcm_bounds.py), and the fuzz suite derives its
structure-aware mutations from it. It uses the standard library only (the build runs it before
anything of marionette exists).

    schemas = load_directory(Path("lcmtypes"))
    spec = schemas["lcmt_controller_spec"]
    [f.name for f in spec.fields]                  # utime, controller_id, name, ...
    spec.field("num_tasks").max                    # the declared maximum count
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

# Encoded size of each primitive [bytes]; strings are a 4-byte length (NUL included) + bytes.
PRIMITIVE_SIZES = {
    "int8_t": 1,
    "int16_t": 2,
    "int32_t": 4,
    "int64_t": 8,
    "float": 4,
    "double": 8,
    "boolean": 1,
    "byte": 1,
}
# Python ``struct`` codes of the primitives (big-endian, as LCM encodes them: prefix ">").
STRUCT_FORMATS = {
    "int8_t": "b",
    "int16_t": "h",
    "int32_t": "i",
    "int64_t": "q",
    "float": "f",
    "double": "d",
    "boolean": "b",
    "byte": "B",
}
INTEGERS = ("int8_t", "int16_t", "int32_t", "int64_t")
NUMBERS = (*INTEGERS, "float", "double")
MIN_STRING_SIZE = 5  # length prefix + NUL
DEFAULT_MAXLEN = 4096  # bytes of a string (NUL excluded) unless the field says @maxlen
MAX_DIMS = 4
MAX_FIELDS = 64  # per struct (the C++ walker keeps their integer values on its stack)
ANNOTATIONS = ("max", "range", "clock", "maxlen")


class SchemaError(ValueError):
    """An .lcm file this reader (or its annotation grammar) refuses; says file:line and why."""


@dataclass(frozen=True)
class Dim:
    """One dimension of an array: a fixed ``size``, or the earlier integer field ``field``
    (whose declared ``@max`` bounds it: ``max``)."""

    size: int | None = None
    field: str | None = None
    max: int = 0

    @property
    def fixed(self) -> bool:
        return self.field is None

    @property
    def fixed_size(self) -> int:
        """The size of a fixed dimension."""
        if self.size is None:
            raise SchemaError(f"{self}: sized by the field {self.field!r}, not fixed")
        return self.size

    @property
    def sizer(self) -> str:
        """The integer field that sizes a variable dimension."""
        if self.field is None:
            raise SchemaError(f"{self}: a fixed dimension, sized by no field")
        return self.field


@dataclass(frozen=True)
class Field:
    name: str
    type: str  # a primitive name, "string", or the name of a struct of the package
    dims: tuple[Dim, ...] = ()
    max: int | None = None  # @max: the largest count, for a field that sizes arrays
    range: tuple[float, float] | None = None  # @range: every value within [lo, hi]
    clock: tuple[float, float] | None = None  # @clock: [now + lo, now + hi] s, controller time
    maxlen: int | None = None  # strings: bytes without the NUL (DEFAULT_MAXLEN if not declared)
    comment: str = ""
    line: int = 0

    @property
    def is_array(self) -> bool:
        return bool(self.dims)

    @property
    def is_primitive(self) -> bool:
        return self.type in PRIMITIVE_SIZES

    @property
    def string_maxlen(self) -> int:
        return DEFAULT_MAXLEN if self.maxlen is None else self.maxlen


@dataclass(frozen=True)
class Struct:
    name: str
    fields: tuple[Field, ...]
    comment: str = ""
    path: str = ""

    def field(self, name: str) -> Field:
        for f in self.fields:
            if f.name == name:
                return f
        raise KeyError(f"{self.name} has no field {name!r}")

    @property
    def dimension_fields(self) -> set[str]:
        return {d.field for f in self.fields for d in f.dims if d.field is not None}


@dataclass
class Schemas:
    """Every struct of the package, by name, with sizes derived from the declared bounds."""

    structs: dict[str, Struct] = field(default_factory=dict)

    def __getitem__(self, name: str) -> Struct:
        return self.structs[name]

    def __iter__(self):
        return iter(self.structs.values())

    def __len__(self) -> int:
        return len(self.structs)

    def min_size(self, name: str) -> int:
        """Bytes of the smallest encoding of struct ``name`` (no fingerprint)."""
        return sum(self._field_size(f, smallest=True) for f in self.structs[name].fields)

    def max_size(self, name: str) -> int:
        """Bytes of the largest encoding the declared bounds allow (no fingerprint)."""
        return sum(self._field_size(f, smallest=False) for f in self.structs[name].fields)

    def _field_size(self, f: Field, smallest: bool) -> int:
        count = 1
        for d in f.dims:
            count *= d.fixed_size if d.fixed else (0 if smallest else d.max)
        if f.type in PRIMITIVE_SIZES:
            element = PRIMITIVE_SIZES[f.type]
        elif f.type == "string":
            element = MIN_STRING_SIZE + (0 if smallest else f.string_maxlen)
        else:
            element = self.min_size(f.type) if smallest else self.max_size(f.type)
        return count * element

    def to_data(self) -> dict[str, Any]:
        """Plain data (what the build writes into the generated Python module)."""
        return {
            s.name: [
                {
                    "name": f.name,
                    "type": f.type,
                    "dims": [[d.size, d.field, d.max] for d in f.dims],
                    "max": f.max,
                    "range": list(f.range) if f.range else None,
                    "clock": list(f.clock) if f.clock else None,
                    "maxlen": f.maxlen,
                }
                for f in s.fields
            ]
            for s in self
        }

    @classmethod
    def from_data(cls, data: dict[str, Any]) -> Schemas:
        """The inverse of :meth:`to_data` (comments and lines are not kept)."""
        structs = {}
        for name, fields in data.items():
            structs[name] = Struct(
                name,
                tuple(
                    Field(
                        f["name"],
                        f["type"],
                        tuple(
                            Dim(size, dim_field, dim_max) for size, dim_field, dim_max in f["dims"]
                        ),
                        f["max"],
                        tuple(f["range"]) if f["range"] else None,
                        tuple(f["clock"]) if f["clock"] else None,
                        f["maxlen"],
                    )
                    for f in fields
                ),
            )
        return cls(structs)

    def bounds_equal(self, other: Schemas) -> bool:
        """Same structs, fields and bounds (comments and line numbers aside)."""
        return self.to_data() == other.to_data()


# ---- reading -------------------------------------------------------------------------------

_FIELD = re.compile(r"^(\w+)\s+(\w+)\s*((?:\[\s*\w+\s*\])*)\s*;$")
_ANNOTATION = re.compile(r"@(\w+)\b\s*([^@]*)")
_NUMBER = r"[-+]?(?:inf|\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)"
_INTERVAL = re.compile(rf"^({_NUMBER})\s*\.\.\s*({_NUMBER})$")


def _number(text: str, integral: bool) -> float:
    value = float(text)
    if integral and math.isfinite(value):
        if value != int(value):
            raise ValueError(f"{text} is not an integer")
        return int(text) if re.fullmatch(r"[-+]?\d+", text) else int(value)
    return value


def _parse_annotations(comment: str, where: str) -> dict[str, str]:
    found: dict[str, str] = {}
    for key, value in _ANNOTATION.findall(comment):
        if key not in ANNOTATIONS:
            raise SchemaError(
                f"{where}: unknown annotation @{key} (one of @{', @'.join(ANNOTATIONS)})"
            )
        if key in found:
            raise SchemaError(f"{where}: @{key} given twice")
        # The value ends at the first word that is not part of it (the comment goes on after).
        found[key] = value.strip().split(" ")[0].rstrip(",;")
    return found


def _interval(text: str, integral: bool, where: str, key: str) -> tuple[float, float]:
    m = _INTERVAL.match(text)
    if not m:
        raise SchemaError(f"{where}: @{key} takes LO..HI (e.g. @{key} 0..1000), got {text!r}")
    try:
        lo, hi = _number(m.group(1), integral), _number(m.group(2), integral)
    except ValueError as e:
        raise SchemaError(f"{where}: @{key} {text}: {e}") from None
    if not lo <= hi:
        raise SchemaError(f"{where}: @{key} {text}: empty interval")
    return lo, hi


def read_struct(path: Path) -> Struct:
    """Reads one ``lcmt_*.lcm`` file: ``package marionette;``, comments, one struct."""
    lines = path.read_text().splitlines()
    header: list[str] = []
    fields: list[Field] = []
    name = None
    state = "header"
    for number, raw in enumerate(lines, start=1):
        where = f"{path.name}:{number}"
        code, _, comment = raw.partition("//")
        code, comment = code.strip(), comment.strip()
        if state == "header":
            if code.startswith("package"):
                if code != "package marionette;":
                    raise SchemaError(f"{where}: expected 'package marionette;'")
                continue
            if code.startswith("struct"):
                parts = code.split()
                if len(parts) != 2:
                    raise SchemaError(f"{where}: expected 'struct NAME'")
                name = parts[1]
                state = "open"
                continue
            if code:
                raise SchemaError(f"{where}: unexpected {code!r} before the struct")
            if comment:
                header.append(comment)
            continue
        if state == "open":
            if code == "{":
                state = "body"
                continue
            if code:
                raise SchemaError(f"{where}: expected '{{'")
            continue
        if state == "body":
            if code == "}":
                state = "closed"
                continue
            if not code:
                if _ANNOTATION.search(comment):
                    raise SchemaError(
                        f"{where}: an annotation must be on its field's line: {comment!r}"
                    )
                continue
            fields.append(_read_field(code, comment, where, number, fields))
            continue
        if code:
            raise SchemaError(f"{where}: unexpected {code!r} after the struct")
    if state != "closed" or name is None:
        raise SchemaError(f"{path.name}: no complete struct")
    if len(fields) > MAX_FIELDS:
        raise SchemaError(f"{path.name}: {len(fields)} fields, at most {MAX_FIELDS}")
    return Struct(name, tuple(fields), " ".join(header), str(path))


def _read_field(code: str, comment: str, where: str, line: int, previous: list[Field]) -> Field:
    m = _FIELD.match(code)
    if not m:
        raise SchemaError(f"{where}: cannot read the field {code!r}")
    type_name, name, dims_text = m.groups()
    known = {f.name: f for f in previous}
    dims = []
    for token in re.findall(r"\[\s*(\w+)\s*\]", dims_text):
        if token.isdigit():
            dims.append(Dim(size=int(token)))
            continue
        sizer = known.get(token)
        if sizer is None or sizer.is_array or sizer.type not in INTEGERS:
            raise SchemaError(
                f"{where}: {name}[{token}]: {token} must be an integer field before it"
            )
        if sizer.max is None:
            raise SchemaError(
                f"{where}: {name}[{token}]: {token} sizes an array and needs a declared maximum "
                f"(// @max N on {token}'s line)"
            )
        dims.append(Dim(field=token, max=sizer.max))
    if len(dims) > MAX_DIMS:
        raise SchemaError(f"{where}: {name}: at most {MAX_DIMS} dimensions")
    notes = _parse_annotations(comment, where)
    numeric = type_name in NUMBERS
    integral = type_name in INTEGERS
    maximum = rng = clock = maxlen = None
    if "max" in notes:
        if not integral or dims:
            raise SchemaError(f"{where}: @max is for an integer field that sizes arrays")
        try:
            maximum = int(notes["max"])
        except ValueError:
            raise SchemaError(f"{where}: @max takes a non-negative integer") from None
        if maximum < 0:
            raise SchemaError(f"{where}: @max takes a non-negative integer")
    if "range" in notes:
        if not numeric:
            raise SchemaError(f"{where}: @range is for numbers, not {type_name}")
        if maximum is not None:
            raise SchemaError(f"{where}: a field with @max is in [0, max] already: no @range")
        rng = _interval(notes["range"], integral, where, "range")
    if "clock" in notes:
        if type_name != "int64_t" or dims:
            raise SchemaError(f"{where}: @clock is for an int64_t time stamp [us]")
        if rng is not None:
            raise SchemaError(f"{where}: @clock and @range exclude each other")
        clock = _interval(notes["clock"], False, where, "clock")
    if "maxlen" in notes:
        if type_name != "string":
            raise SchemaError(f"{where}: @maxlen is for strings")
        try:
            maxlen = int(notes["maxlen"])
        except ValueError:
            raise SchemaError(f"{where}: @maxlen takes a non-negative integer") from None
        if maxlen < 0:
            raise SchemaError(f"{where}: @maxlen takes a non-negative integer")
    return Field(name, type_name, tuple(dims), maximum, rng, clock, maxlen, comment, line)


def load_directory(directory: Path) -> Schemas:
    """Every ``lcmt_*.lcm`` of ``directory``, checked: struct names match their files, field
    types exist, every array dimension is bounded."""
    structs: dict[str, Struct] = {}
    for path in sorted(Path(directory).glob("lcmt_*.lcm")):
        s = read_struct(path)
        if s.name != path.stem:
            raise SchemaError(f"{path.name}: struct {s.name} must be named like its file")
        structs[s.name] = s
    for s in structs.values():
        for f in s.fields:
            if f.type not in PRIMITIVE_SIZES and f.type != "string" and f.type not in structs:
                raise SchemaError(f"{Path(s.path).name}:{f.line}: unknown type {f.type}")
    schemas = Schemas(structs)
    for s in structs.values():
        schemas.min_size(s.name)  # raises RecursionError on a recursive type
    return schemas
