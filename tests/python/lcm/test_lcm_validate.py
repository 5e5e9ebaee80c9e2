"""The schema of lcmtypes/ with its bounds (marionette.lcm_schema), the validator the build
generates from it (marionette.lcm_validate; the C++ twin is tested in tests/cpp/lcm), and the
structure-aware mutations of the fuzz suite (marionette.lcm_fuzz): random valid messages of every
type pass and decode unchanged, every mutation of every type is refused, random bytes never make
the validator raise."""

from __future__ import annotations

import random
import struct

import pytest

import marionette
from marionette import lcmt_controller_spec, lcmt_dg_request, lcmt_task_reference
from marionette.control.fuzz import INPUTS
from marionette.lcm_fuzz import KINDS, Fuzzer, layout, random_message
from marionette.lcm_schema import NUMBERS, SchemaError, Schemas, load_directory, read_struct
from marionette.lcm_validate import REASONS, schemas, validate

ROOT = marionette.REPO_ROOT
NOW_US = 50_000_000


def _types():
    return [getattr(marionette, s.name) for s in schemas()]


def test_every_file_reads_and_the_build_generated_the_same_bounds():
    read = load_directory(ROOT / "lcmtypes")
    assert len(read) == len(list((ROOT / "lcmtypes").glob("*.lcm")))
    # The tables in the build (C++ and Python come from the same generator) are up to date.
    assert read.bounds_equal(schemas()), "rebuild: the build's lcm_bounds are stale"
    generated = (marionette.BUILD_DIR / "lcmtypes/cpp/marionette/lcm_bounds.hpp").read_text()
    for s in read:
        assert f'"{s.name}"' in generated


def test_every_numeric_input_of_the_controller_declares_its_range():
    """Gains, limits, timeouts, durations, time stamps, velocities: every number the controller
    takes (nested types included) is bounded next to its field, every count by a @max."""
    s = schemas()
    seen: set[str] = set()
    missing = []

    def walk(name: str) -> None:
        if name in seen:
            return
        seen.add(name)
        for f in s[name].fields:
            if f.type in NUMBERS and f.range is None and f.clock is None and f.max is None:
                missing.append(f"{name}.{f.name}")
            if f.type in s.structs:
                walk(f.type)

    for lcm_type in INPUTS.values():
        walk(lcm_type.__name__)
    assert missing == []
    assert seen >= {"lcmt_task_spec", "lcmt_footstep"}
    # The stream's time stamps are checked against the controller's clock.
    assert s["lcmt_task_reference"].field("utime").clock == (-10.0, 10.0)


@pytest.mark.parametrize(
    "body, error",
    [
        ("  int32_t n;\n  double x[n];", "needs a declared maximum"),
        ("  string s;  // @range 0..1", "@range is for numbers"),
        ("  double x;  // @unknown 3", "unknown annotation @unknown"),
        ("  double x;\n  // @range 0..1", "must be on its field's line"),
        ("  double x;  // @range 1..0", "empty interval"),
        ("  int32_t n;  // @max -1", "non-negative"),
        ("  double x[m];", "must be an integer field before it"),
        ("  int64_t t;  // @clock 0..1 @range 0..1", "exclude each other"),
    ],
)
def test_annotation_mistakes_are_refused_with_their_line(tmp_path, body, error):
    path = tmp_path / "lcmt_bad.lcm"
    path.write_text(f"package marionette;\nstruct lcmt_bad\n{{\n  int64_t utime;\n{body}\n}}\n")
    with pytest.raises(SchemaError, match=error) as info:
        read_struct(path)
    assert "lcmt_bad.lcm:" in str(info.value)


def test_sizes_follow_from_the_declared_bounds(tmp_path):
    path = tmp_path / "lcmt_x.lcm"
    path.write_text(
        "package marionette;\nstruct lcmt_x\n{\n  int64_t utime;\n"
        "  int32_t n;  // @max 3\n  double v[n][2];  // [m]\n  string s;  // @maxlen 10\n}\n"
    )
    s = Schemas({"lcmt_x": read_struct(path)})
    assert s.min_size("lcmt_x") == 8 + 4 + 5
    assert s.max_size("lcmt_x") == 8 + 4 + 3 * 2 * 8 + 5 + 10


@pytest.mark.parametrize("seed", range(3))
def test_random_valid_messages_of_every_type_pass_and_decode_unchanged(seed):
    rng = random.Random(seed)
    for lcm_type in _types():
        for _ in range(20):
            data = random_message(lcm_type, rng, now_us=NOW_US).encode()
            assert validate(lcm_type, data, NOW_US) is None, lcm_type.__name__
            assert lcm_type.decode(data).encode() == data
            assert layout(lcm_type, data)  # the fuzzer finds every value's place


@pytest.mark.parametrize("seed", range(2))
def test_every_kind_of_mutation_of_every_type_is_refused(seed):
    rng = random.Random(seed)
    fuzzer = Fuzzer(rng)
    pool = [random_message(t, rng).encode() for t in (marionette.lcmt_walk_status, lcmt_dg_request)]
    seen_kinds, seen_reasons = set(), set()
    for lcm_type in _types():
        base = random_message(lcm_type, rng, max_count=2, now_us=NOW_US).encode()
        others = [o for o in pool if o[:8] != base[:8]]  # another type's message
        for _ in range(150):
            data, kind = fuzzer.mutate(lcm_type, base, others, NOW_US)
            refusal = validate(lcm_type, data, NOW_US)
            if refusal is None:
                # Only when the lie is no lie: random bytes of exactly a fixed-size type's length,
                # or a count of rows whose other dimension is 0 (sampled_path's nq with no
                # samples). Then the bytes are a faithful valid message.
                assert kind in ("random_body", "length_lie"), (lcm_type.__name__, kind)
                assert lcm_type.decode(data).encode() == data
                continue
            assert refusal.reason in REASONS
            seen_kinds.add(kind)
            seen_reasons.add(refusal.reason)
    assert seen_kinds == set(KINDS)
    assert seen_reasons == set(REASONS)


def test_random_bytes_never_make_the_validator_raise():
    rng = random.Random(7)
    for lcm_type in _types():
        fingerprint = lcm_type._get_packed_fingerprint()
        for _ in range(200):
            data = fingerprint + rng.randbytes(rng.randrange(0, 300))
            if validate(lcm_type, data) is None:
                lcm_type.decode(data)  # what passes decodes


def test_refusals_name_the_field_and_the_bound():
    spec = lcmt_controller_spec()
    spec.max_switch_velocity_jump, spec.reference_timeout = 0.1, 0.1
    spec.num_tasks = 1
    task = marionette.lcmt_task_spec()
    task.name, task.kind, task.gain = "t", "posture", 1e300
    spec.tasks = [task]
    refusal = validate(lcmt_controller_spec, spec.encode())
    assert (refusal.reason, refusal.detail) == (
        "out of range",
        "tasks[0].gain: 1e+300 outside [0, 1000]",
    )

    request = lcmt_dg_request()
    request.command, request.num_values, request.value = "set", 1, [2.0]
    data = bytearray(request.encode())
    struct.pack_into(">i", data, 8 + 8 + 8 + 5 + 8 + 4, 1 << 27)  # num_values = 2^27
    refusal = validate(lcmt_dg_request, bytes(data))
    assert (refusal.reason, refusal.detail) == ("over maximum", "num_values: 134217728 > 4096")

    chunk = lcmt_task_reference()
    chunk.utime, chunk.dt_us = (1 << 63) - 1, 1000
    refusal = validate(lcmt_task_reference, chunk.encode(), NOW_US)
    assert refusal.reason == "time out of range" and "the controller's time is 50 s" in str(refusal)
