"""Where to look for tags in the next frame: the regions of interest of a tag tracker.

Between two frames of a 30 Hz camera a tag moves a fraction of its own size in the image, so the
next search needs only a box around each tag's last corners, grown by a margin: a few percent of
the image instead of all of it (AprilTag's work grows with the pixels it segments, and with
sensor noise every one of them counts). The whole image is still searched

* every ``full_search_every`` frames, so that tags entering the view are found within that many
  frames;
* after a frame where a tracked tag was not found in its box (it moved further than the margin,
  or left the view), so that a lost tag costs one frame;
* while no tag is tracked.

A tag that is no longer found (seen too obliquely, blurred, hidden for a moment) keeps its last
box for ``keep_lost_frames`` frames, so that it is found again where it was without waiting for
the next whole-image search. Tags are told apart by id (a scene's ids are unique).

A box that reaches the image border is clipped by the detector; overlapping boxes are merged
there, so a tag is found once.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from marionette.perception.detector import TagDetection

Box = tuple[int, int, int, int]  # (u0, v0, u1, v1): columns u0..u1-1, rows v0..v1-1


@dataclass(frozen=True)
class TrackingConfig:
    """How far a tag may move between frames and how often the whole image is searched."""

    full_search_every: int = 10  # [frames]; 1: every frame searches the whole image
    # Margin around a tag's corner box, per side: this fraction of its size in the image (the
    # white border alone is 1/8 of it), at least min_margin_px.
    margin_fraction: float = 0.5
    min_margin_px: int = 16
    # [frames] a tag's box is searched until this many frames after the one that last saw it
    # (1: only the last frame's tags; 30: ~1 s at 30 Hz)
    keep_lost_frames: int = 30

    def __post_init__(self) -> None:
        if self.full_search_every < 1:
            raise ValueError(f"full_search_every must be >= 1, got {self.full_search_every}")
        if not self.margin_fraction >= 0.0 or self.min_margin_px < 0:
            raise ValueError("margin_fraction and min_margin_px must be >= 0")
        if self.keep_lost_frames < 1:  # 0 would forget the tags just seen: never track
            raise ValueError(f"keep_lost_frames must be >= 1, got {self.keep_lost_frames}")


def tag_box(corners: np.ndarray, config: TrackingConfig) -> Box:
    """The box to search for a tag whose last corners were ``corners`` (4, 2) [px]."""
    lo, hi = corners.min(axis=0), corners.max(axis=0)
    margin = max(config.min_margin_px, config.margin_fraction * float(np.max(hi - lo)))
    return (
        int(np.floor(lo[0] - margin)),
        int(np.floor(lo[1] - margin)),
        int(np.ceil(hi[0] + margin)) + 1,
        int(np.ceil(hi[1] + margin)) + 1,
    )


class TagRegionTracker:
    """Chooses each frame's search regions from the tags seen in the last frames.

    Use: ``regions = tracker.regions()``, detect with them, then ``tracker.update(detections,
    regions)``. ``counts`` says how many frames were searched whole, in regions, and how many
    regional searches lost a tracked tag.
    """

    def __init__(self, config: TrackingConfig | None = None) -> None:
        self.config = config or TrackingConfig()
        self._frame = 0
        self._last_seen: dict[int, tuple[Box, int]] = {}  # tag id -> (box, frame seen)
        self._since_full = 0
        self._lost = False
        self.counts = {"full_searches": 0, "regional_searches": 0, "tracked_tags_lost": 0}

    def regions(self) -> list[Box] | None:
        """The boxes to search in the next frame, or None for the whole image."""
        if (
            not self._last_seen
            or self._lost
            or self._since_full + 1 >= self.config.full_search_every
        ):
            return None
        return [box for box, _ in self._last_seen.values()]

    def update(self, detections: Sequence[TagDetection], regions: Sequence[Box] | None) -> None:
        """Records what a search over ``regions`` (None: the whole image) found."""
        found = {d.tag_id for d in detections}
        if regions is None:
            self.counts["full_searches"] += 1
            self._since_full = 0
            self._lost = False
        else:
            self.counts["regional_searches"] += 1
            self._since_full += 1
            previous = {i for i, (_, frame) in self._last_seen.items() if frame == self._frame}
            lost = len(previous - found)
            self.counts["tracked_tags_lost"] += lost
            self._lost = lost > 0
        self._frame += 1
        for d in detections:
            self._last_seen[d.tag_id] = (tag_box(np.asarray(d.corners), self.config), self._frame)
        oldest = self._frame - self.config.keep_lost_frames
        self._last_seen = {i: seen for i, seen in self._last_seen.items() if seen[1] > oldest}
