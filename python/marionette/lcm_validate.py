"""Bounded validation of LCM messages before they are decoded — the Python twin of
cpp/include/marionette/lcm/validate.h, walking the same generated tables (``lcm_bounds``, built
from lcmtypes/*.lcm by the build) with the same checks in the same order and the same reasons:

    refusal = validate(lcmt_task_reference, data, now_us=None)   # None: the message is fine
    refusal.reason, refusal.detail   # "over maximum", "num_samples: 4096 > 1000"

Every array count and string length is checked against the bytes that remain and its declared
maximum, every annotated number against its range (NaN never passes), before lcm-gen's decoder
runs: a refused message costs a walk over its bytes, never an allocation it declares.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from functools import cache
from typing import Any, Protocol, cast

import numpy as np

from marionette.lcm_schema import MIN_STRING_SIZE, PRIMITIVE_SIZES, STRUCT_FORMATS, Schemas

# The reasons, as the controller counts them (wire::ToString).
WRONG_TYPE = "wrong type"
PAST_THE_END = "past the end"
NEGATIVE_LENGTH = "negative length"
OVER_MAXIMUM = "over maximum"
UNTERMINATED_STRING = "unterminated string"
NOT_BOOLEAN = "not a boolean"
OUT_OF_RANGE = "out of range"
TIME_OUT_OF_RANGE = "time out of range"
TRAILING_BYTES = "trailing bytes"
REASONS = (
    WRONG_TYPE,
    PAST_THE_END,
    NEGATIVE_LENGTH,
    OVER_MAXIMUM,
    UNTERMINATED_STRING,
    NOT_BOOLEAN,
    OUT_OF_RANGE,
    TIME_OUT_OF_RANGE,
    TRAILING_BYTES,
)


class LcmType(Protocol):
    """An lcm-gen message class (``marionette.lcmt_*``): what this module and its users call."""

    __name__: str

    def __call__(self) -> Any: ...  # a message, every field zero

    def decode(self, data: bytes) -> Any: ...

    def _get_packed_fingerprint(self) -> bytes: ...


@dataclass(frozen=True)
class Refusal:
    reason: str  # one of REASONS
    detail: str  # the field, its value and its bound

    def __str__(self) -> str:
        return f"{self.reason}: {self.detail}"


# Where the walk is, formatted only for a refusal: None (the message), or (parent, field name,
# element index or None, dimensions).
Where = tuple | None


def _format(where: Where) -> str:
    if where is None:
        return ""
    parent, name, e, dims = where
    head = _format(parent)
    return (f"{head}.{name}" if head else name) + ("" if e is None else _index(e, dims))


class _Refused(Exception):
    def __init__(self, reason: str, where: Where, what: str) -> None:
        super().__init__(reason)
        path = _format(where)
        self.refusal = Refusal(reason, f"{path}: {what}" if path and what else path or what)


@cache
def schemas() -> Schemas:
    """The generated schema of every type (what the C++ walker's tables hold too)."""
    from marionette import lcm_bounds

    return Schemas.from_data(lcm_bounds.SCHEMA)


def _g(x: float) -> str:
    return f"{x:.6g}"


@dataclass(frozen=True)
class _Op:
    """One field, prepared for the walk (what the C++ tables hold per field)."""

    name: str
    kind: str  # "number" (a primitive), "string", "struct"
    type: str
    codec: struct.Struct | None
    size: int  # primitives; the smallest element otherwise
    dims: tuple[tuple[int, int], ...]  # (fixed size, -1), or (0, the sizing field's index)
    read: bool  # primitives: each value is read (counts, booleans, ranges, clocks)
    integer: bool
    boolean: bool
    max: int | None
    range: tuple[float, float] | None
    clock: tuple[float, float] | None
    maxlen: int


@cache
def _plan(name: str) -> tuple[_Op, ...]:
    s = schemas()
    fields = s[name].fields
    index = {f.name: i for i, f in enumerate(fields)}
    ops = []
    for f in fields:
        primitive = f.type in PRIMITIVE_SIZES
        kind = "number" if primitive else "string" if f.type == "string" else "struct"
        size = (
            PRIMITIVE_SIZES[f.type]
            if primitive
            else MIN_STRING_SIZE
            if kind == "string"
            else s.min_size(f.type)
        )
        boolean = f.type == "boolean"
        ops.append(
            _Op(
                f.name,
                kind,
                f.type,
                struct.Struct(">" + STRUCT_FORMATS[f.type]) if primitive else None,
                size,
                tuple((d.fixed_size, -1) if d.fixed else (0, index[d.sizer]) for d in f.dims),
                primitive
                and (boolean or f.max is not None or f.range is not None or f.clock is not None),
                f.type not in ("float", "double") and primitive,
                boolean,
                f.max,
                f.range,
                f.clock,
                f.string_maxlen,
            )
        )
    return tuple(ops)


class _Walker:
    def __init__(self, data: bytes, now_us: int | None) -> None:
        self.data = memoryview(data)
        self.size = len(data)
        self.pos = 0
        self.now_us = now_us

    def walk_struct(self, name: str, path: Where) -> None:
        ops = _plan(name)
        integers = [0] * len(ops)
        for i, op in enumerate(ops):
            if not op.dims:
                value = self.element(op, (path, op.name, None, None))
                if op.integer:
                    integers[i] = cast(int, value)  # an integer format unpacks to an int
                continue
            dims = [fixed if sizer < 0 else integers[sizer] for fixed, sizer in op.dims]
            if 0 in dims:
                continue
            count = 1
            for n in dims:
                count *= n  # every partial count is at most the whole
                left = self.size - self.pos
                if count > left // op.size:
                    raise _Refused(
                        PAST_THE_END,
                        (path, op.name, None, None),
                        f"{count} elements of at least {op.size} bytes, {left} bytes left",
                    )
            if op.kind == "number" and not op.read:
                self.pos += count * op.size  # nobody bounds them: skipped whole
                continue
            if op.type == "double" and op.clock is None and op.range is not None and count > 8:
                # Many doubles: the range check in numpy, the first offender named as C++ does.
                values = np.frombuffer(self.data, dtype=">f8", count=count, offset=self.pos)
                lo, hi = op.range
                bad = np.flatnonzero(~((values >= lo) & (values <= hi)))
                if bad.size == 0:
                    self.pos += count * 8
                    continue
                self.pos += int(bad[0]) * 8
                self.element(op, (path, op.name, int(bad[0]), dims))
                raise AssertionError("unreachable: the element was out of range")
            if op.kind == "string":
                for e in range(count):
                    self.string(op, path, e, dims)
                continue
            for e in range(count):
                self.element(op, (path, op.name, e, dims))

    def element(self, op: _Op, where: tuple) -> int | float | None:
        if op.kind == "string":
            self.string(op, where[0], where[2], where[3])
            return None
        if op.kind == "struct":
            self.walk_struct(op.type, where)
            return None
        left = self.size - self.pos
        if left < op.size:
            raise _Refused(PAST_THE_END, where, f"{op.size} bytes needed, {left} left")
        assert op.codec is not None  # every "number" op has its codec (_plan)
        (value,) = op.codec.unpack_from(self.data, self.pos)
        self.pos += op.size
        if not op.read:
            return value
        if op.boolean and value not in (0, 1):
            raise _Refused(NOT_BOOLEAN, where, f"byte {value & 0xFF} (0 or 1)")
        if op.max is not None:
            if value < 0:
                raise _Refused(NEGATIVE_LENGTH, where, str(value))
            if value > op.max:
                raise _Refused(OVER_MAXIMUM, where, f"{value} > {op.max}")
        if op.range is not None:
            lo, hi = op.range
            if not (lo <= float(value) <= hi):
                raise _Refused(OUT_OF_RANGE, where, f"{_g(value)} outside [{_g(lo)}, {_g(hi)}]")
        if op.clock is not None:
            if value < 0:  # controller time starts at 0
                raise _Refused(TIME_OUT_OF_RANGE, where, f"{_g(value * 1e-6)} s < 0")
            if self.now_us is not None:
                lo, hi = op.clock
                if not (self.now_us + 1e6 * lo <= float(value) <= self.now_us + 1e6 * hi):
                    raise _Refused(
                        TIME_OUT_OF_RANGE,
                        where,
                        f"{_g(value * 1e-6)} s, the controller's time is "
                        f"{_g(self.now_us * 1e-6)} s (accepted: {_g(lo)} to +{_g(hi)} s from it)",
                    )
        return value

    def string(self, op: _Op, path: Where, e: int | None, dims: list[int] | None) -> None:
        left = self.size - self.pos
        where = (path, op.name, e, dims)
        if left < 4:
            raise _Refused(PAST_THE_END, where, f"a string length needs 4 bytes, {left} left")
        (length,) = _INT32.unpack_from(self.data, self.pos)
        self.pos += 4
        left -= 4
        if length < 1:
            raise _Refused(NEGATIVE_LENGTH, where, f"string length {length} (at least 1: the NUL)")
        if length > left:
            raise _Refused(PAST_THE_END, where, f"string of {length} bytes, {left} left")
        if self.data[self.pos + length - 1] != 0:
            raise _Refused(UNTERMINATED_STRING, where, "no NUL at its end")
        if length - 1 > op.maxlen:
            raise _Refused(OVER_MAXIMUM, where, f"string of {length - 1} bytes > {op.maxlen}")
        self.pos += length


_INT32 = struct.Struct(">i")


def _index(e: int, dims: list[int]) -> str:
    out = []
    for n in reversed(dims):
        out.append(e % n)
        e //= n
    return "".join(f"[{i}]" for i in reversed(out))


def validate(lcm_type: LcmType, data: bytes, now_us: int | None = None) -> Refusal | None:
    """Why ``data`` is not one ``lcm_type`` message within its declared bounds, or None.
    ``@clock`` fields must be >= 0 and, with ``now_us`` (controller time), lie in their window
    around it."""
    name = lcm_type.__name__
    if len(data) < 8 or bytes(data[:8]) != lcm_type._get_packed_fingerprint():
        detail = (
            f"{len(data)} bytes, no fingerprint"
            if len(data) < 8
            else f"the fingerprint is not {name}'s"
        )
        return Refusal(WRONG_TYPE, detail)
    w = _Walker(data, now_us)
    w.pos = 8
    try:
        w.walk_struct(name, None)
    except _Refused as refused:
        return refused.refusal
    if w.size > w.pos:
        return Refusal(TRAILING_BYTES, f"{w.size - w.pos} bytes after the {w.pos} of the message")
    return None
