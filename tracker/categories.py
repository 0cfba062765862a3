"""The category vocabulary shared by every dataset.

Boxes store a category as an int index into :data:`CATEGORIES`, so per-category thresholds are
arrays indexed by that int and "never match across categories" is one integer comparison.
The tuple only grows at the end: indices written to disk by older versions stay valid.
"""

from __future__ import annotations

from typing import Final

CATEGORIES: Final[tuple[str, ...]] = (
    # tracked classes (KITTI, nuScenes, Waymo)
    "car",
    "pedestrian",
    "cyclist",
    "bicycle",
    "motorcycle",
    "bus",
    "trailer",
    "truck",
    # KITTI ground-truth-only classes, kept so the evaluator can treat them as distractors
    "van",
    "person_sitting",
    "tram",
    "misc",
    "dontcare",
)

CATEGORY_INDEX: Final[dict[str, int]] = {name: i for i, name in enumerate(CATEGORIES)}

#: Spellings seen in the wild, mapped to the canonical lower-case name.
ALIASES: Final[dict[str, str]] = {
    "person (sitting)": "person_sitting",
    "person_sitting": "person_sitting",
    "vehicle": "car",
}


def category_index(name: str) -> int:
    """Index of a category name (case-insensitive, aliases allowed); -1 when unknown."""
    key = name.strip().lower()
    key = ALIASES.get(key, key)
    return CATEGORY_INDEX.get(key, -1)
