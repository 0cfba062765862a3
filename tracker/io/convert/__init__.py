"""Dataset converters: raw benchmark files → world-frame :class:`~tracker.frame.Frame` lists."""

from __future__ import annotations

from tracker.io.convert.kitti import convert_kitti

__all__ = ["convert_kitti"]
