"""CHANNELS.md, channels.h and channels.py list the same channels, with existing types."""

from __future__ import annotations

import re

import marionette
from marionette import channels

ROOT = marionette.REPO_ROOT


def _markdown_channels() -> dict[str, str]:
    text = (ROOT / "lcmtypes" / "CHANNELS.md").read_text()
    return dict(re.findall(r"^\| `([A-Z_]+)` \| `(lcmt_[a-z_]+)` \|", text, flags=re.M))


def _cpp_channels() -> set[str]:
    text = (ROOT / "cpp" / "include" / "marionette" / "lcm" / "channels.h").read_text()
    return set(re.findall(r'inline constexpr char k\w+\[\] = "([A-Z_]+)";', text))


def _python_channels() -> set[str]:
    return {v for k, v in vars(channels).items() if k.isupper() and isinstance(v, str)}


def test_three_lists_agree():
    md = set(_markdown_channels())
    assert len(md) >= 14
    assert _cpp_channels() == md
    assert _python_channels() == md


def test_python_constant_names_match_values():
    for name, value in vars(channels).items():
        if name.isupper():
            assert name == value


def test_every_listed_type_exists_and_imports():
    for channel, type_name in _markdown_channels().items():
        assert (ROOT / "lcmtypes" / f"{type_name}.lcm").exists(), channel
        lcm_type = getattr(marionette, type_name)
        assert lcm_type.decode(lcm_type().encode()) is not None


def test_every_type_follows_the_convention():
    for path in sorted((ROOT / "lcmtypes").glob("*.lcm")):
        text = path.read_text()
        assert re.search(r"^package marionette;", text, flags=re.M), path.name
        struct = re.search(r"struct (\w+)\s*\{(.*?)\}", text, flags=re.S)
        assert struct and struct.group(1) == path.stem, f"{path.name}: one type named like its file"
        fields = [ln.split("//")[0].strip() for ln in struct.group(2).splitlines()]
        fields = [f for f in fields if f]
        assert fields[0] == "int64_t utime;", f"{path.name}: utime must come first"
        assert not any(f.startswith("float ") for f in fields), f"{path.name}: use double"
        declared = {f.split()[1].rstrip(";") for f in fields if not f.split()[1].endswith("]")}
        for f in fields:
            for size in re.findall(r"\[(\w+)\]", f):
                assert size.isdigit() or size in declared, (
                    f"{path.name}: {size} declared before use"
                )
