"""Imported once by the local pool's fork server (app/scenes.py): loads the tracker and its
compiled kernels there, so every worker forked from it starts warm (a fresh process spends
1-2 s loading the kernels on its first frame)."""

from __future__ import annotations

from tracker.config import load_config
from tracker.io.synthetic import synthetic_scene
from tracker.pipeline import run_scene

_frames, _ = synthetic_scene(num_objects=4, num_frames=5, seed=0)
run_scene(_frames, load_config("kitti"))
