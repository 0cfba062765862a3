"""The KITTI evaluation per sequence (one TrackEval loading each, in the scene task) combined
afterwards equals TrackEval's own Evaluator over all sequences at once."""

from __future__ import annotations

import contextlib
import io
import shutil
from pathlib import Path

import pytest

from app.kitti import run_kitti
from tracker.eval.kitti import _summarise

SEQS = ["0001", "0006"]
CLASSES = ["car", "pedestrian", "cyclist"]


def _trackeval_evaluator(label_dir: Path, result_dir: Path, lengths: dict[str, int], tmp: Path):
    """TrackEval's Evaluator on all sequences at once: the reference combination."""
    import trackeval

    from tracker.eval.kitti import _cyclist_dataset

    gt_root, trackers = tmp / "gt", tmp / "trackers" / "mctrack" / "data"
    (gt_root / "label_02").mkdir(parents=True)
    trackers.mkdir(parents=True)
    for seq in lengths:
        shutil.copy(label_dir / f"{seq}.txt", gt_root / "label_02")
        shutil.copy(result_dir / f"{seq}.txt", trackers)
    (gt_root / "evaluate_tracking.seqmap.val").write_text(
        "".join(f"{s} empty 000000 {n:06d}\n" for s, n in sorted(lengths.items()))
    )
    config = {
        "GT_FOLDER": str(gt_root),
        "TRACKERS_FOLDER": str(tmp / "trackers"),
        "OUTPUT_FOLDER": str(tmp / "out"),
        "TRACKERS_TO_EVAL": ["mctrack"],
        "SPLIT_TO_EVAL": "val",
        "PRINT_CONFIG": False,
    }
    eval_config = trackeval.Evaluator.get_default_eval_config()
    eval_config.update(
        PRINT_RESULTS=False, PRINT_CONFIG=False, TIME_PROGRESS=False, OUTPUT_SUMMARY=False,
        OUTPUT_DETAILED=False, PLOT_CURVES=False, USE_PARALLEL=False,
    )  # fmt: skip
    metrics = [
        trackeval.metrics.HOTA(),
        trackeval.metrics.CLEAR({"PRINT_CONFIG": False}),
        trackeval.metrics.Identity({"PRINT_CONFIG": False}),
    ]
    out, per_seq = {}, {}
    runs = [
        (trackeval.datasets.Kitti2DBox({**config, "CLASSES_TO_EVAL": ["car", "pedestrian"]}), ""),
        (_cyclist_dataset(trackeval, config), "cyclist"),
    ]
    for dataset, rename in runs:
        with contextlib.redirect_stdout(io.StringIO()):
            results, _ = trackeval.Evaluator(eval_config).evaluate([dataset], metrics)
        by_seq = results[dataset.get_name()]["mctrack"]
        for cls in ("car",) if rename else ("car", "pedestrian"):
            name = rename or cls
            out[name] = _summarise(by_seq["COMBINED_SEQ"][cls])
            for seq in lengths:
                per_seq.setdefault(seq, {})[name] = _summarise(by_seq[seq][cls])
    return out, per_seq


@pytest.mark.parametrize("record", [False, True], ids=["plain", "record"])
def test_per_sequence_evaluation_combines_like_trackeval(
    kitti_root: Path, tmp_path: Path, record: bool
) -> None:
    out = tmp_path / "run"
    summary = run_kitti(
        kitti_root=kitti_root,
        seqs=SEQS,
        classes=CLASSES,
        out=out,
        record=out / "recordings" if record else None,
        quiet=True,
    )
    lengths = _sequence_lengths(kitti_root, SEQS)
    expected, expected_per_seq = _trackeval_evaluator(
        kitti_root / "training" / "label_02", out / "data", lengths, tmp_path / "ref"
    )
    for cls, metrics in expected.items():
        if metrics["TP"] + metrics["FN"] == 0:  # no GT of the class: reported as absent
            assert cls in summary["metrics_absent"]
        else:
            assert summary["metrics"][cls] == metrics, cls
    for seq, per in summary["per_sequence"].items():
        for cls, counts in per.items():
            assert counts == {k: expected_per_seq[seq][cls][k] for k in ("IDSW", "Frag")}


def _sequence_lengths(kitti_root: Path, seqs: list[str]) -> dict[str, int]:
    from tracker.io.convert.kitti import convert_kitti

    detections, _ = convert_kitti(kitti_root, seqs=seqs, classes=CLASSES)
    return {s: len(frames) for s, frames in detections.items()}
