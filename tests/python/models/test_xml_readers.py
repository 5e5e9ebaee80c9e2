"""The URDF, SRDF and MJCF readers answer a file that lacks an attribute or an element they need
with one error naming that element, never an AttributeError or a TypeError.

Every bundled file is mutilated once per kind of attribute and of element it holds (the same
tag path from the root): each is removed in its first occurrence, then the file is read again.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Iterator

import pytest

from marionette import MODELS_DIR, robots
from marionette.models.urdf import UrdfError, parse_urdf

# A big URDF takes seconds: hundreds of mutilations, each read again whole.
URDFS = [
    pytest.param(p, marks=pytest.mark.slow) if p.stat().st_size > 30_000 else p
    for p in sorted(MODELS_DIR.glob("*/*.urdf"))
]
# What a reader says when a file lacks something: "...: <tag> has no 'attr' attribute" or
# "...: <tag> has no <child> element".
MISSING = re.compile(r"<(\w+)> has no ('\w+' attribute|<\w+> element)")


def _mutilations(text: str, tags: tuple[str, ...] = ()) -> Iterator[tuple[str, str]]:
    """(what was removed, the text without it), once per tag path and attribute name, for the
    elements whose tag is in ``tags`` (default: every element but the root)."""
    seen: set[str] = set()
    for path, steps, element in _walk(ET.fromstring(text), "", ()):
        if not steps or (tags and element.tag not in tags):
            continue
        for key in [None, *element.attrib]:
            what = f"{path}:{key}" if key else f"{path} element"
            if what in seen:
                continue
            seen.add(what)
            copy = ET.fromstring(text)
            parent = copy
            for i in steps[:-1]:
                parent = parent[i]
            if key:
                del parent[steps[-1]].attrib[key]
            else:
                del parent[steps[-1]]
            yield what, ET.tostring(copy, encoding="unicode")


def _walk(
    e: ET.Element, path: str, steps: tuple[int, ...]
) -> Iterator[tuple[str, tuple[int, ...], ET.Element]]:
    """(tag path, child indices from the root, element) of ``e`` and every element below it."""
    here = f"{path}/{e.tag}"
    yield here, steps, e
    for i, c in enumerate(e):
        yield from _walk(c, here, (*steps, i))


@pytest.mark.parametrize("path", URDFS, ids=lambda p: p.stem)
def test_a_urdf_missing_an_attribute_or_element_names_it(path):
    removed = 0
    for what, text in _mutilations(path.read_text()):
        try:
            parse_urdf(text)
        except UrdfError as e:
            assert MISSING.search(str(e)), f"{what}: {e}"
            removed += 1
    assert removed > 0, "no removal was refused: the reader checks nothing"


@pytest.mark.parametrize("name", robots.robot_names())
def test_an_srdf_state_missing_an_attribute_names_it(name):
    desc = robots.robot(name)
    model, _ = robots.load_pinocchio(name, with_collision=False)
    sem = robots.semantics(name)
    text = desc.srdf.read_text()
    states = ET.fromstring(text).findall("group_state")
    index = next(i for i, s in enumerate(states) if s.get("name") == desc.reference)
    for path, key in (("", "name"), ("joint", "name"), ("joint", "value")):
        root = ET.fromstring(text)
        state = root.findall("group_state")[index]
        target = state.find(path) if path else state
        assert target is not None
        del target.attrib[key]
        with pytest.raises(ValueError, match=MISSING.pattern):
            robots.configuration_from_srdf(
                model, ET.tostring(root, encoding="unicode"), desc.reference, sem
            )


@pytest.mark.parametrize("name", robots.robot_names())
def test_an_mjcf_joint_missing_its_name_is_named(name):
    text = robots.robot(name).mjcf.read_text()
    for what, mutilated in _mutilations(text, tags=("joint",)):
        needed = ("/worldbody/" in what and what.endswith(":name")) or (
            "/equality/" in what and what.endswith(":joint1")
        )
        if needed:
            with pytest.raises(ValueError, match=MISSING.pattern):
                robots.mujoco_layout(ET.fromstring(mutilated))
        else:  # other attributes are not the layout's business
            robots.mujoco_layout(ET.fromstring(mutilated))
