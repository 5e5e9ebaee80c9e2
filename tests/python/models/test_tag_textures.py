"""The AprilTag textures of models/textures: read back, each is its tag, bit for bit, and
AprilTag 3's own detector decodes it with the corner order of ViSP's default tag frame."""

from __future__ import annotations

import ctypes
import ctypes.util
import re

import numpy as np
import pytest
from PIL import Image

from marionette import MODELS_DIR, robots
from marionette.models import apriltag
from marionette.models.mjcf import TAG_PIXELS_PER_CELL

TEXTURES = sorted((MODELS_DIR / "textures").glob("tag36h11_*.png"))


def _tag_id(path) -> int:
    return int(re.fullmatch(r"tag36h11_(\d{5})\.png", path.name).group(1))


def _cells(image: np.ndarray, cell: int) -> np.ndarray:
    """Grey level at the centre of every cell (rows, cols)."""
    n = image.shape[0] // cell
    centres = np.arange(n) * cell + cell // 2
    return image[np.ix_(centres, centres)]


def test_every_declared_tag_has_a_texture_and_nothing_else():
    declared = {t.id for o in robots.object_names() for t in robots.load_object(o).semantics.tags}
    declared |= {t.id for n in robots.robot_names() for t in robots.semantics(n).tags}
    assert {_tag_id(p) for p in TEXTURES} == declared


@pytest.mark.parametrize("path", TEXTURES, ids=lambda p: p.stem)
def test_texture_is_its_tag_bit_for_bit(path):
    image = np.asarray(Image.open(path))
    assert image.dtype == np.uint8 and image.ndim == 2  # 8-bit grey
    assert image.shape == (10 * TAG_PIXELS_PER_CELL,) * 2
    cells = _cells(image, TAG_PIXELS_PER_CELL)
    # Every cell is uniform: sharp edges for the detector.
    blocks = image.reshape(10, TAG_PIXELS_PER_CELL, 10, TAG_PIXELS_PER_CELL)
    assert np.all(blocks.min(axis=(1, 3)) == blocks.max(axis=(1, 3)))
    assert set(np.unique(cells)) <= {0, 255}
    white = cells == 255
    # The white border (1 cell, needed by detectors), then the 8 x 8 black-bordered square
    # whose data bits come from the family's code word (not from the rendered image).
    assert white[0, :].all() and white[-1, :].all() and white[:, 0].all() and white[:, -1].all()
    assert np.array_equal(white[1:-1, 1:-1], apriltag.tag_payload(_tag_id(path)))
    assert not white[1, 1:-1].any() and not white[-2, 1:-1].any()


class _Detection(ctypes.Structure):
    _fields_ = [
        ("family", ctypes.c_void_p),
        ("id", ctypes.c_int),
        ("hamming", ctypes.c_int),
        ("decision_margin", ctypes.c_float),
        ("H", ctypes.c_void_p),
        ("c", ctypes.c_double * 2),
        ("p", (ctypes.c_double * 2) * 4),
    ]


class _Zarray(ctypes.Structure):
    _fields_ = [
        ("el_sz", ctypes.c_size_t),
        ("size", ctypes.c_int),
        ("alloc", ctypes.c_int),
        ("data", ctypes.c_void_p),
    ]


class _Image(ctypes.Structure):
    _fields_ = [
        ("width", ctypes.c_int32),
        ("height", ctypes.c_int32),
        ("stride", ctypes.c_int32),
        ("buf", ctypes.POINTER(ctypes.c_uint8)),
    ]


def _detect(gray: np.ndarray) -> list[tuple[int, int, np.ndarray]]:
    """(id, hamming, corners p (4, 2) in pixels) of every tag36h11 AprilTag 3 finds."""
    lib = ctypes.CDLL(ctypes.util.find_library("apriltag") or "libapriltag.so.3")
    lib.tag36h11_create.restype = ctypes.c_void_p
    lib.apriltag_detector_create.restype = ctypes.c_void_p
    lib.apriltag_detector_add_family_bits.argtypes = [
        ctypes.c_void_p,
        ctypes.c_void_p,
        ctypes.c_int,
    ]
    lib.apriltag_detector_detect.restype = ctypes.POINTER(_Zarray)
    lib.apriltag_detector_detect.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Image)]
    lib.apriltag_detections_destroy.argtypes = [ctypes.POINTER(_Zarray)]
    lib.apriltag_detector_destroy.argtypes = [ctypes.c_void_p]
    lib.tag36h11_destroy.argtypes = [ctypes.c_void_p]
    family = lib.tag36h11_create()
    detector = lib.apriltag_detector_create()
    lib.apriltag_detector_add_family_bits(detector, family, 2)
    buf = np.ascontiguousarray(gray, dtype=np.uint8)
    image = _Image(
        buf.shape[1], buf.shape[0], buf.shape[1], buf.ctypes.data_as(ctypes.POINTER(ctypes.c_uint8))
    )
    found = lib.apriltag_detector_detect(detector, ctypes.byref(image))
    out = []
    pointers = ctypes.cast(found.contents.data, ctypes.POINTER(ctypes.POINTER(_Detection)))
    for i in range(found.contents.size):
        d = pointers[i].contents
        out.append((d.id, d.hamming, np.array([[d.p[k][0], d.p[k][1]] for k in range(4)])))
    lib.apriltag_detections_destroy(found)
    lib.apriltag_detector_destroy(detector)
    lib.tag36h11_destroy(family)
    return out


@pytest.mark.parametrize("path", TEXTURES, ids=lambda p: p.stem)
def test_apriltag_detector_decodes_the_texture_with_visps_corner_order(path):
    """On the upright texture (row 0 on top), AprilTag 3 reports corners p[0..3] at the
    bottom-left, bottom-right, top-right and top-left of the black square. ViSP's default
    tag frame puts them at (-s/2, -s/2), (s/2, -s/2), (s/2, s/2), (-s/2, s/2): x right, y up in
    the upright image, z towards the viewer, the convention of models/README.md."""
    image = np.pad(np.asarray(Image.open(path)), 40, constant_values=255)
    detections = _detect(image)
    assert [(d[0], d[1]) for d in detections] == [(_tag_id(path), 0)]
    p = detections[0][2]  # (u, v): u right, v down
    c = TAG_PIXELS_PER_CELL
    left, right, top, bottom = 40 + c, 40 + 9 * c, 40 + c, 40 + 9 * c  # black square edges
    expected = np.array([[left, bottom], [right, bottom], [right, top], [left, top]])
    assert np.abs(p - expected).max() < 1.0


def test_write_tag_png_round_trip_and_bad_ids(tmp_path):
    path = apriltag.write_tag_png(tmp_path / "t.png", 7, pixels_per_cell=4)
    assert np.array_equal(np.asarray(Image.open(path)), apriltag.tag_image(7, 4))
    with pytest.raises(ValueError, match=r"tag36h11 has tags 0..586, got 587"):
        apriltag.tag_image(587)
    with pytest.raises(ValueError, match="unsupported tag family"):
        apriltag.tag_code(1, "tag16h5")
    assert apriltag.printed_size(0.08) == pytest.approx(0.1)
