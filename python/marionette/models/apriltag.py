"""AprilTag images straight from the AprilTag 3 library's family data (Debian libapriltag).

``apriltag_to_image(family, id)`` renders a tag as one pixel per cell, white border included
(tag36h11: 10 x 10 cells, the black square is the inner 8 x 8). We upscale it with whole cells
so a texture keeps sharp edges, and write it as an 8-bit grey PNG.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from functools import cache
from pathlib import Path

import numpy as np

FAMILIES = ("tag36h11",)


class _Family(ctypes.Structure):
    # apriltag.h (AprilTag 3.3): struct apriltag_family.
    _fields_ = [
        ("ncodes", ctypes.c_uint32),
        ("codes", ctypes.POINTER(ctypes.c_uint64)),
        ("width_at_border", ctypes.c_int),
        ("total_width", ctypes.c_int),
        ("reversed_border", ctypes.c_bool),
        ("nbits", ctypes.c_uint32),
        ("bit_x", ctypes.POINTER(ctypes.c_uint32)),
        ("bit_y", ctypes.POINTER(ctypes.c_uint32)),
        ("h", ctypes.c_uint32),
        ("name", ctypes.c_char_p),
        ("impl", ctypes.c_void_p),
    ]


class _ImageU8(ctypes.Structure):
    # common/image_types.h: struct image_u8.
    _fields_ = [
        ("width", ctypes.c_int32),
        ("height", ctypes.c_int32),
        ("stride", ctypes.c_int32),
        ("buf", ctypes.POINTER(ctypes.c_uint8)),
    ]


@cache
def _library() -> tuple[ctypes.CDLL, ctypes.CDLL]:
    """(libapriltag, libapriltag-utils): Debian puts the image_u8 helpers in the second."""
    try:
        lib = ctypes.CDLL(ctypes.util.find_library("apriltag") or "libapriltag.so.3")
        utils = ctypes.CDLL(ctypes.util.find_library("apriltag-utils") or "libapriltag-utils.so.3")
    except OSError as e:
        raise RuntimeError(
            f"cannot load libapriltag ({e}); scripts/setup installs libapriltag-dev"
        ) from e
    lib.tag36h11_create.restype = ctypes.POINTER(_Family)
    lib.apriltag_to_image.restype = ctypes.POINTER(_ImageU8)
    lib.apriltag_to_image.argtypes = [ctypes.POINTER(_Family), ctypes.c_int]
    utils.image_u8_destroy.argtypes = [ctypes.POINTER(_ImageU8)]
    return lib, utils


@cache
def _family(name: str):
    if name not in FAMILIES:
        raise ValueError(f"unsupported tag family {name!r}; supported: {FAMILIES}")
    return getattr(_library()[0], f"{name}_create")().contents


def family_size(family: str = "tag36h11") -> int:
    """Number of distinct tags in ``family``."""
    return int(_family(family).ncodes)


def tag_code(tag_id: int, family: str = "tag36h11") -> int:
    """The family's code word of ``tag_id`` (nbits bits, most significant bit first)."""
    fam = _family(family)
    _check_id(tag_id, fam, family)
    return int(fam.codes[tag_id])


def tag_payload(tag_id: int, family: str = "tag36h11") -> np.ndarray:
    """The black-bordered square (width_at_border^2 cells, True = white) from the code word.

    Bit i of the code (counted from the most significant) is the cell at column bit_x[i],
    row bit_y[i] of that square; every other cell is black. This is an independent reading of
    the family data, to check the rendered images against.
    """
    fam = _family(family)
    code = tag_code(tag_id, family)
    n = fam.width_at_border
    cells = np.zeros((n, n), dtype=bool)
    for i in range(fam.nbits):
        bit = (code >> (fam.nbits - 1 - i)) & 1
        cells[fam.bit_y[i], fam.bit_x[i]] = bool(bit)
    return cells


def tag_cells(tag_id: int, family: str = "tag36h11") -> np.ndarray:
    """The full tag (total_width^2 cells, uint8: 0 black, 255 white), rendered by the library."""
    fam = _family(family)
    _check_id(tag_id, fam, family)
    lib, utils = _library()
    im = lib.apriltag_to_image(ctypes.byref(fam), tag_id)
    try:
        w, h, stride = im.contents.width, im.contents.height, im.contents.stride
        raw = np.ctypeslib.as_array(im.contents.buf, shape=(h * stride,))
        return raw.reshape(h, stride)[:, :w].copy()
    finally:
        utils.image_u8_destroy(im)


def tag_image(tag_id: int, pixels_per_cell: int = 16, family: str = "tag36h11") -> np.ndarray:
    """The tag upscaled with square cells of ``pixels_per_cell`` pixels (uint8, H x W)."""
    if pixels_per_cell < 1:
        raise ValueError(f"pixels_per_cell must be >= 1, got {pixels_per_cell}")
    cells = tag_cells(tag_id, family)
    return np.kron(cells, np.ones((pixels_per_cell, pixels_per_cell), dtype=np.uint8))


def border_cells(family: str = "tag36h11") -> int:
    """White border width in cells on each side (total_width - width_at_border) / 2."""
    fam = _family(family)
    return (fam.total_width - fam.width_at_border) // 2


def printed_size(size: float, family: str = "tag36h11") -> float:
    """Edge [m] of the printed tag, white border included, for a black square of ``size``."""
    fam = _family(family)
    return size * fam.total_width / fam.width_at_border


def write_tag_png(
    path: str | Path, tag_id: int, pixels_per_cell: int = 16, family: str = "tag36h11"
) -> Path:
    """Write the tag as an 8-bit grey PNG (no metadata, so the bytes are reproducible)."""
    from PIL import Image

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(tag_image(tag_id, pixels_per_cell, family), mode="L").save(
        path, format="PNG", optimize=False, compress_level=9
    )
    return path


def texture_name(tag_id: int, family: str = "tag36h11") -> str:
    """File stem of a tag texture, e.g. ``tag36h11_00010``."""
    return f"{family}_{tag_id:05d}"


def _check_id(tag_id: int, fam, family: str) -> None:
    if not isinstance(tag_id, (int, np.integer)) or not 0 <= tag_id < fam.ncodes:
        raise ValueError(f"{family} has tags 0..{fam.ncodes - 1}, got {tag_id!r}")
