"""Static KITTI evaluation with the field's standard: TrackEval (PyPI ``trackeval``), KITTI 2D-box
protocol (HOTA, CLEAR, Identity): 2D IoU on image boxes, occlusion <= 2, truncation <= 0,
height >= 25 px, DontCare regions, Van a distractor for Car, Person_sitting for Pedestrian.

TrackEval's ``Kitti2DBox`` only accepts car and pedestrian. Cyclist is scored with the same
protocol and no distractor class (``_CyclistKitti2DBox``), reported separately and labelled so.
"""

from __future__ import annotations

import contextlib
import io
import shutil
import tempfile
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tracker.io.fileio import path_in

SUPPORTED_CLASSES = ("car", "pedestrian", "cyclist")


def evaluate_kitti(
    *,
    label_dir: Path,
    result_dir: Path,
    seq_lengths: Mapping[str, int],
    classes: Sequence[str] = ("car", "pedestrian"),
    per_sequence: dict[str, dict[str, dict[str, float]]] | None = None,
) -> dict[str, dict[str, float]]:
    """Evaluate ``result_dir/<seq>.txt`` against ``label_dir/<seq>.txt``.

    Returns, per class, HOTA, DetA, AssA, LocA, MOTA, MOTP, IDF1 (percent), IDSW, Frag, FP, FN,
    TP (counts) over the combined sequences. A ``per_sequence`` dict given is filled with the
    same per sequence (``{seq: {class: metrics}}``; TrackEval computes them anyway).
    """
    import trackeval  # heavy import: only when evaluating

    unknown = [c for c in classes if c not in SUPPORTED_CLASSES]
    if unknown:
        raise ValueError(f"cannot evaluate classes {unknown}; supported: {SUPPORTED_CLASSES}")
    with tempfile.TemporaryDirectory(prefix="mctrack-eval-") as tmp:
        gt_root, trackers_root = Path(tmp) / "gt", Path(tmp) / "trackers"
        (gt_root / "label_02").mkdir(parents=True)
        (trackers_root / "mctrack" / "data").mkdir(parents=True)
        seqmap = []
        for seq, length in sorted(seq_lengths.items()):
            shutil.copyfile(
                path_in(label_dir, seq, ".txt"), path_in(gt_root / "label_02", seq, ".txt")
            )
            result = path_in(result_dir, seq, ".txt")
            target = path_in(trackers_root / "mctrack" / "data", seq, ".txt")
            if result.is_file():
                shutil.copyfile(result, target)
            else:
                target.write_text("")
            seqmap.append(f"{seq} empty 000000 {length:06d}\n")
        (gt_root / "evaluate_tracking.seqmap.val").write_text("".join(seqmap))

        eval_config = trackeval.Evaluator.get_default_eval_config()
        eval_config.update(
            PRINT_RESULTS=False,
            PRINT_CONFIG=False,
            TIME_PROGRESS=False,
            OUTPUT_SUMMARY=False,
            OUTPUT_DETAILED=False,
            PLOT_CURVES=False,
            USE_PARALLEL=False,
            DISPLAY_LESS_PROGRESS=True,
        )
        metrics = [
            trackeval.metrics.HOTA(),
            trackeval.metrics.CLEAR({"PRINT_CONFIG": False}),
            trackeval.metrics.Identity({"PRINT_CONFIG": False}),
        ]
        out: dict[str, dict[str, float]] = {}
        standard = [c for c in classes if c in ("car", "pedestrian")]
        runs: list[tuple[Any, list[str]]] = []
        ds_config = {
            "GT_FOLDER": str(gt_root),
            "TRACKERS_FOLDER": str(trackers_root),
            "OUTPUT_FOLDER": str(Path(tmp) / "out"),
            "TRACKERS_TO_EVAL": ["mctrack"],
            "SPLIT_TO_EVAL": "val",
            "PRINT_CONFIG": False,
        }
        if standard:
            runs.append(
                (
                    trackeval.datasets.Kitti2DBox({**ds_config, "CLASSES_TO_EVAL": standard}),
                    standard,
                )
            )
        if "cyclist" in classes:
            runs.append((_cyclist_dataset(trackeval, ds_config), ["cyclist"]))
        for dataset, names in runs:
            with contextlib.redirect_stdout(io.StringIO()):
                evaluator = trackeval.Evaluator(eval_config)
                results, _messages = evaluator.evaluate([dataset], metrics)
            by_seq = results[dataset.get_name()]["mctrack"]
            for name in names:
                key = "car" if name == "cyclist" else name  # see _cyclist_dataset
                out[name] = _summarise(by_seq["COMBINED_SEQ"][key])
                if per_sequence is not None:
                    for seq in sorted(seq_lengths):
                        per_sequence.setdefault(seq, {})[name] = _summarise(by_seq[seq][key])
        return out


def absent_classes(metrics: Mapping[str, Mapping[str, float]]) -> list[str]:
    """Classes with no ground-truth object in the evaluated frames (TP + FN = 0): their scores
    only count false positives (MOTA -21200) and mean nothing, so reports show them as absent."""
    return [c for c, m in metrics.items() if m["TP"] + m["FN"] == 0]


def _summarise(res: dict[str, dict[str, Any]]) -> dict[str, float]:
    hota, clear, ident = res["HOTA"], res["CLEAR"], res["Identity"]
    pct = lambda v: round(float(np.mean(v)) * 100.0, 3)  # noqa: E731
    return {
        "HOTA": pct(hota["HOTA"]),
        "DetA": pct(hota["DetA"]),
        "AssA": pct(hota["AssA"]),
        "LocA": pct(hota["LocA"]),
        "MOTA": pct(clear["MOTA"]),
        "MOTP": pct(clear["MOTP"]),
        "IDF1": pct(ident["IDF1"]),
        "IDSW": int(clear["IDSW"]),
        "Frag": int(clear["Frag"]),
        "FP": int(clear["CLR_FP"]),
        "FN": int(clear["CLR_FN"]),
        "TP": int(clear["CLR_TP"]),
    }


def _cyclist_dataset(trackeval: Any, ds_config: dict[str, Any]) -> Any:
    """Kitti2DBox scoring Cyclist: ids are remapped so that the 'car' code path (the only
    evaluatable one besides pedestrian) reads the cyclist class and has no distractor."""

    class _CyclistKitti2DBox(trackeval.datasets.Kitti2DBox):  # type: ignore[misc]
        def get_preprocessed_seq_data(self, raw_data: Any, cls: str) -> Any:
            original = self.class_name_to_class_id
            self.class_name_to_class_id = {**original, "car": original["cyclist"], "van": -1}
            try:
                return super().get_preprocessed_seq_data(raw_data, "car")
            finally:
                self.class_name_to_class_id = original

    return _CyclistKitti2DBox({**ds_config, "CLASSES_TO_EVAL": ["car"]})
