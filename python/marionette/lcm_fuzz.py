"""Structure-aware mutations of LCM messages, derived from the schema of lcmtypes/
(:mod:`marionette.lcm_schema`): the fuzz suite (tests/python/fuzz) and the soak benchmark
(bench/lcm_soak) send them to marionette-controller.

A valid message is laid out field by field (:func:`layout`: where each count, string length,
number and boolean sits in its bytes), then one lie is told about it:

    length_lie   an array count: -1, -2^31, 2^30, 2^31 - 1, its @max + 1, one more than sent...
    string_lie   a string's length prefix: 0, -1, -2^31, 2^30, one more or one less than sent
    truncate     cut anywhere
    extend       random bytes appended
    random_body  the type's fingerprint, then random bytes
    wrong_type   a valid message of another channel's type
    nan_inf      NaN (quiet, signalling, negative), +-inf in a ranged number
    extreme      a ranged number just or far outside its range, a time stamp at +-2^63, -1,
                 +-10^9 s from the controller's clock
    bad_boolean  a boolean byte of 2..255

    fuzzer = Fuzzer(random.Random(0))
    data, kind = fuzzer.mutate(lcmt_task_reference, valid_bytes, pool, now_us)
"""

from __future__ import annotations

import random
import struct
from collections.abc import Sequence
from dataclasses import dataclass

from marionette.lcm_schema import INTEGERS, PRIMITIVE_SIZES, STRUCT_FORMATS, Field, Schemas
from marionette.lcm_validate import LcmType, schemas

KINDS = (
    "length_lie",
    "string_lie",
    "truncate",
    "extend",
    "random_body",
    "wrong_type",
    "nan_inf",
    "extreme",
    "bad_boolean",
)


@dataclass(frozen=True)
class Slot:
    """Where one value sits in a message's bytes."""

    path: str
    field: Field
    offset: int
    size: int
    role: str  # "count" (sizes arrays), "string" (a length prefix), "number", "boolean", "other"
    value: int | float = 0


def layout(lcm_type: LcmType, data: bytes, schema: Schemas | None = None) -> list[Slot]:
    """Every value of the valid message ``data`` (an ``lcm_type`` encoding) and its place."""
    schema = schema or schemas()
    slots: list[Slot] = []
    pos = 8

    def walk(name: str, path: str) -> None:
        nonlocal pos
        integers: dict[str, int] = {}
        for f in schema[name].fields:
            where = f"{path}.{f.name}" if path else f.name
            count = 1
            for d in f.dims:
                count *= d.fixed_size if d.fixed else integers[d.sizer]
            for e in range(count):
                at = where + (f"[{e}]" if f.dims else "")
                if f.type == "string":
                    (length,) = struct.unpack_from(">i", data, pos)
                    slots.append(Slot(at, f, pos, 4, "string", length))
                    pos += 4 + length
                elif f.type in PRIMITIVE_SIZES:
                    size = PRIMITIVE_SIZES[f.type]
                    (value,) = struct.unpack_from(">" + STRUCT_FORMATS[f.type], data, pos)
                    if f.max is not None:
                        role = "count"
                    elif f.type == "boolean":
                        role = "boolean"
                    elif f.range is not None or f.clock is not None:
                        role = "number"
                    else:
                        role = "other"
                    slots.append(Slot(at, f, pos, size, role, value))
                    if not f.dims:
                        integers[f.name] = value
                    pos += size
                else:
                    walk(f.type, at)

    walk(lcm_type.__name__, "")
    if pos != len(data):
        raise ValueError(f"{lcm_type.__name__}: layout ends at {pos}, the message at {len(data)}")
    return slots


def _int_limits(type_name: str) -> tuple[int, int]:
    bits = 8 * PRIMITIVE_SIZES[type_name]
    return -(1 << (bits - 1)), (1 << (bits - 1)) - 1


class Fuzzer:
    """Mutations of valid messages, one lie each, drawn from ``rng``."""

    def __init__(self, rng: random.Random, schema: Schemas | None = None) -> None:
        self.rng = rng
        self.schema = schema or schemas()
        self._layouts: dict[tuple[str, bytes], dict[str, list[Slot]]] = {}

    def _roles(self, lcm_type: LcmType, data: bytes) -> dict[str, list[Slot]]:
        """The message's slots by role ("real": the ranged floating-point numbers)."""
        key = (lcm_type.__name__, data)
        if key not in self._layouts:
            if len(self._layouts) > 256:
                self._layouts.clear()
            by_role: dict[str, list[Slot]] = {}
            for s in layout(lcm_type, data, self.schema):
                by_role.setdefault(s.role, []).append(s)
                if s.role == "number" and s.field.type in ("double", "float"):
                    by_role.setdefault("real", []).append(s)
            self._layouts[key] = by_role
        return self._layouts[key]

    def mutate(
        self,
        lcm_type: LcmType,
        data: bytes,
        others: Sequence[bytes] = (),
        now_us: int = 0,
        kind: str | None = None,
    ) -> tuple[bytes, str]:
        """One mutation of the valid ``data`` (its ``kind``, drawn when None); ``others``: valid
        messages of other types (wrong_type); ``now_us``: the controller's time (time stamps)."""
        rng = self.rng
        by_role = self._roles(lcm_type, data)
        possible = [
            k
            for k in KINDS
            if (k != "length_lie" or "count" in by_role)
            and (k != "string_lie" or "string" in by_role)
            and (k != "wrong_type" or others)
            and (k != "nan_inf" or "real" in by_role)
            and (k != "extreme" or "number" in by_role)
            and (k != "bad_boolean" or "boolean" in by_role)
        ]
        kind = kind or rng.choice(possible)
        out = bytearray(data)
        if kind == "length_lie":
            s = rng.choice(by_role["count"])
            top = s.field.max
            assert top is not None  # a "count" slot is a field with its @max
            lo, hi = _int_limits(s.field.type)
            lie = rng.choice(
                [-1, -2, lo, 1 << 30, hi, top + 1, s.value + 1, 2 * s.value + 7]
                + ([0, s.value - 1] if s.value > 0 else [])
            )
            lie = max(lo, min(hi, lie))
            if lie == s.value:
                lie = s.value + 1
            struct.pack_into(">" + STRUCT_FORMATS[s.field.type], out, s.offset, lie)
        elif kind == "string_lie":
            s = rng.choice(by_role["string"])
            lie = rng.choice([0, -1, -(1 << 31), 1 << 30, (1 << 31) - 1, s.value + 1, s.value - 1])
            if lie == s.value:
                lie = 0
            struct.pack_into(">i", out, s.offset, lie)
        elif kind == "truncate":
            out = out[: rng.randrange(0, len(out))]
        elif kind == "extend":
            out += rng.randbytes(rng.randrange(1, 65))
        elif kind == "random_body":
            out = out[:8] + rng.randbytes(rng.randrange(0, 2 * len(out)))
        elif kind == "wrong_type":
            out = bytearray(rng.choice(others))
        elif kind == "nan_inf":
            s = rng.choice(by_role["real"])
            bits = rng.choice(
                [
                    0x7FF8000000000000,
                    0x7FF0000000000001,
                    0xFFF8000000000000,
                    0x7FF0000000000000,
                    0xFFF0000000000000,
                ]
            )
            if s.field.type == "double":
                struct.pack_into(">Q", out, s.offset, bits)
            else:
                struct.pack_into(">f", out, s.offset, struct.unpack(">d", bits.to_bytes(8))[0])
        elif kind == "extreme":
            s = rng.choice(by_role["number"])
            struct.pack_into(
                ">" + STRUCT_FORMATS[s.field.type], out, s.offset, self._extreme(s, now_us)
            )
        elif kind == "bad_boolean":
            s = rng.choice(by_role["boolean"])
            out[s.offset] = rng.randrange(2, 256)
        return bytes(out), kind

    def _extreme(self, s: Slot, now_us: int) -> int | float:
        rng = self.rng
        f = s.field
        if f.clock is not None:
            tlo, thi = _int_limits(f.type)
            return rng.choice(
                [
                    tlo,
                    thi,
                    -1,
                    now_us - 1_000_000_000_000_000,
                    now_us + 1_000_000_000_000_000,
                    now_us + int(2e6 * f.clock[1]) + 1_000_000,
                    now_us + int(2e6 * f.clock[0]) - 1_000_000,
                ]
            )
        assert f.range is not None  # a "number" slot has a @range or a @clock
        lo, hi = f.range
        if f.type in INTEGERS:  # the type's limits, and just outside the range (as a double is)
            tlo, thi = _int_limits(f.type)
            options = [tlo, max(tlo, int(lo) - 1 - abs(int(lo)) // 2**40)] if lo > tlo else []
            options += [thi, min(thi, int(hi) + 1 + abs(int(hi)) // 2**40)] if hi < thi else []
            return rng.choice(options)
        span = max(hi - lo, 1.0)
        return rng.choice(
            [lo - 1e-3 * span, hi + 1e-3 * span, -1e300, 1e300, -1.7e308, 1.7e308, hi * 1e10 + 1]
        )


def random_message(lcm_type: LcmType, rng: random.Random, max_count: int = 3, now_us: int = 0):
    """A valid ``lcm_type`` message with random content within its declared bounds (arrays of at
    most ``max_count`` elements, strings of at most 12 characters, time stamps around
    ``now_us``): what the validator must pass and lcm-gen's decoder return unchanged."""
    import marionette

    schema = schemas()

    def value(f: Field):
        if f.type == "string":
            n = rng.randrange(0, min(f.string_maxlen, 12) + 1)
            return "".join(rng.choice("abcdefghijklmnopqrstuvwxyz_/.:") for _ in range(n))
        if f.type == "boolean":
            return rng.random() < 0.5
        if f.type == "byte":
            return rng.randrange(256)
        if f.type in INTEGERS:
            if f.clock is not None:
                return now_us + rng.randint(int(1e6 * f.clock[0]), int(1e6 * f.clock[1]))
            lo, hi = _int_limits(f.type)
            if f.range is not None:
                lo, hi = max(lo, int(f.range[0])), min(hi, int(f.range[1]))
            return rng.randint(lo, min(hi, lo + (1 << 40)))
        if f.type in ("double", "float"):
            if f.range is None:
                return rng.gauss(0.0, 1e3)
            return rng.uniform(max(f.range[0], -1e12), min(f.range[1], 1e12))
        return build(getattr(marionette, f.type))

    def build(t: LcmType):
        msg = t()
        counts: dict[str, int] = {}
        for f in schema[t.__name__].fields:
            if f.max is not None:  # sizes arrays: chosen before them
                counts[f.name] = rng.randint(0, min(f.max, max_count))
                setattr(msg, f.name, counts[f.name])
                continue
            dims = [d.fixed_size if d.fixed else counts[d.sizer] for d in f.dims]

            def fill(level: int, f=f, dims=dims):
                if level == len(dims):
                    return value(f)
                return [fill(level + 1) for _ in range(dims[level])]

            v = fill(0)
            if f.type == "byte" and dims:  # lcm-gen's Python takes bytes for byte arrays
                v = bytes(v) if len(dims) == 1 else v
            setattr(msg, f.name, v)
        return msg

    return build(lcm_type)
