"""The official nuScenes tracking evaluation (AMOTA, AMOTP, MOTA, IDS, recall, ...).

A thin wrapper around the devkit's ``TrackingEval`` with the ``tracking_nips_2019`` config, as
the reference (spec §5.2) but with the split, version and dataroot as parameters instead of
hard-coded ``val`` / ``v1.0-trainval``. Needs the ``nuscenes`` extra and the devkit
(docs/nuscenes_waymo.md); it runs under numpy 2 (the devkit's ``numpy<2`` pin is not needed by
the tracking evaluation).
"""

from __future__ import annotations

import contextlib
import io
import json
import math
import warnings
from pathlib import Path
from typing import Any, Final

from tracker.errors import InputError
from tracker.io.convert.nuscenes import SPLIT_VERSION_SUFFIX, check_tables, require_devkit
from tracker.io.fileio import write_text_atomic

EVAL_CONFIG: Final = "tracking_nips_2019"
#: Metrics reported per class and overall (devkit names; lower-case).
METRICS: Final[tuple[str, ...]] = (
    "amota",
    "amotp",
    "recall",
    "motar",
    "mota",
    "motp",
    "mt",
    "ml",
    "faf",
    "tp",
    "fp",
    "fn",
    "ids",
    "frag",
    "tid",
    "lgd",
)

#: The fields of a tracking submission's box (devkit ``TrackingBox.deserialize``).
SUBMISSION_BOX_FIELDS: Final = frozenset(
    ("sample_token", "translation", "size", "rotation", "velocity", "tracking_id",
     "tracking_name", "tracking_score")
)  # fmt: skip

#: Why a submission without a single box is not evaluated: the devkit's TrackingEval cannot
#: (it stops with "Invalid box type: None"), and no metric it did not compute is made up here.
NO_BOXES_NOTE: Final = "skipped: no boxes to evaluate (the submission is empty: nothing tracked)"


def evaluate_nuscenes(
    results_path: str | Path,
    *,
    dataroot: str | Path,
    version: str,
    split: str,
    out_dir: str | Path,
    verbose: bool = False,
    boxes: int | None = None,
) -> dict[str, Any] | str:
    """Run the devkit's ``TrackingEval`` on a tracking submission file.

    Parameters
    ----------
    results_path : the tracking ``results.json`` (:mod:`tracker.io.nuscenes_writer`).
    dataroot, version : the nuScenes tables (``DATAROOT/<version>/``).
    split : the evaluated split (``val``, ``mini_val``, or a custom split); it must contain
        exactly the samples of the results file.
    out_dir : the devkit's output folder; ``metrics_summary.json`` is written there.
    verbose : let the devkit print its progress and tables.
    boxes : the submission's number of boxes when the caller knows it (else counted here).

    Returns
    -------
    ``{"overall": {metric: value}, "per_class": {class: {metric: value}}, ...}`` with NaN as
    None (classes without ground truth in the split are NaN and left out of the averages); for a
    submission without a box, :data:`NO_BOXES_NOTE` (nothing written to ``out_dir``).
    """
    require_devkit()
    check_tables(dataroot, version)
    check_split_has_ground_truth(split)
    if (boxes if boxes is not None else submission_box_count(results_path)) == 0:
        return NO_BOXES_NOTE
    from nuscenes.eval.common.config import config_factory
    from nuscenes.eval.tracking.evaluate import TrackingEval

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sink = io.StringIO()  # the devkit prints progress bars and tables unless verbose
    with contextlib.ExitStack() as stack, warnings.catch_warnings():
        warnings.simplefilter("ignore", FutureWarning)
        warnings.simplefilter("ignore", DeprecationWarning)
        if not verbose:
            stack.enter_context(contextlib.redirect_stdout(sink))
            stack.enter_context(contextlib.redirect_stderr(sink))
        try:
            evaluation = TrackingEval(
                config=config_factory(EVAL_CONFIG),
                result_path=str(results_path),
                eval_set=split,
                output_dir=str(out),
                nusc_version=version,
                nusc_dataroot=str(dataroot),
                verbose=verbose,
            )
            metrics, _ = evaluation.evaluate()
        except AssertionError as exc:
            raise InputError(f"{results_path}: nuScenes TrackingEval: {exc}") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise InputError(f"{results_path}: malformed JSON ({exc})") from None
        except KeyError as exc:  # the devkit's loader reads each box's fields by name
            if exc.args and exc.args[0] in SUBMISSION_BOX_FIELDS:
                raise InputError(
                    f"{results_path}: a box has no field {exc.args[0]!r}: not a tracking "
                    "submission (a detection results file is tracked first: mctrack nuscenes)"
                ) from None
            raise
    serialized = metrics.serialize()
    label = serialized["label_metrics"]
    result: dict[str, Any] = {
        "evaluator": f"nuscenes-devkit {_devkit_version()} TrackingEval ({EVAL_CONFIG})",
        "version": version,
        "split": split,
        "overall": {m: _finite(serialized.get(m)) for m in METRICS if m in serialized},
        "per_class": {
            name: {m: _finite(label[m][name]) for m in METRICS if m in label}
            for name in sorted(next(iter(label.values())).keys())
        },
        "eval_seconds": round(float(serialized.get("eval_time", 0.0)), 3),
    }
    write_text_atomic(out / "metrics_summary.json", [json.dumps(result, indent=2) + "\n"])
    return result


def submission_box_count(results_path: str | Path) -> int | None:
    """The number of boxes in a submission, or None when it is not one the devkit would read
    (its own loader then names what is wrong)."""
    try:
        with open(results_path, encoding="utf-8") as fh:
            data = json.load(fh)
    except (OSError, ValueError):
        return None
    results = data.get("results") if isinstance(data, dict) else None
    if not isinstance(results, dict):
        return None
    return sum(len(v) if isinstance(v, list) else 1 for v in results.values())


def check_split_has_ground_truth(split: str) -> None:
    """InputError for the test split: it has no public annotations to evaluate against."""
    if split == "test" or SPLIT_VERSION_SUFFIX.get(split) == "test":
        raise InputError("the nuScenes test split has no public ground truth: submit instead")


def load_results_with_devkit(results_path: str | Path) -> tuple[Any, dict[str, Any]]:
    """``(EvalBoxes, meta)``: the submission loaded by the devkit's own ``load_prediction``.

    Raises an :class:`InputError` with the devkit's message when it rejects the file (unknown
    tracking name, NaN values, more than 500 boxes in a sample, ...).
    """
    require_devkit()
    from nuscenes.eval.common.config import config_factory
    from nuscenes.eval.common.loaders import load_prediction
    from nuscenes.eval.tracking.data_classes import TrackingBox

    cfg = config_factory(EVAL_CONFIG)  # also registers the tracking class names (a global)
    try:
        return load_prediction(str(results_path), cfg.max_boxes_per_sample, TrackingBox)
    except (AssertionError, KeyError, TypeError) as exc:
        raise InputError(f"{results_path}: rejected by the nuScenes devkit: {exc!r}") from None


def _finite(value: Any) -> float | None:
    if value is None:
        return None
    number = float(value)
    return number if math.isfinite(number) else None


def _devkit_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("nuscenes-devkit")
    except PackageNotFoundError:
        return "unknown"


def nuscenes_markdown(result: dict[str, Any], *, heading_level: int = 2) -> str:
    """The metrics as a markdown table (overall row first)."""
    cols = ["amota", "amotp", "recall", "mota", "motp", "ids", "frag", "tp", "fp", "fn"]
    lines = [
        f"{'#' * heading_level} nuScenes tracking metrics ({result['split']}, {result['version']})",
        "",
        "| class | " + " | ".join(c.upper() for c in cols) + " |",
        "|---|" + "---:|" * len(cols),
    ]
    rows = [("overall", result["overall"]), *result["per_class"].items()]
    for name, metrics in rows:
        cells = [_cell(metrics.get(c)) for c in cols]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join([*lines, "", f"_{result['evaluator']}_", ""])


def _cell(value: float | None) -> str:
    if value is None:
        return "n/a"
    return f"{value:.0f}" if float(value).is_integer() and abs(value) >= 2 else f"{value:.3f}"
