"""Detector score calibration: raw detector scores → probability that the box is a real object.

Every score threshold of the tracker (``score_min``, ``birth_score_min``, ``confirm_score``,
the evidence needed to confirm a track, the offline track score) is a probability, so it
means the same thing for every detector. A :class:`ScoreProfile` holds, per class, a monotone
piecewise-linear map fitted on labelled sequences (:mod:`tracker.eval.calibrate`, isotonic
regression) and stored as a small TOML file; profiles for the detectors of the KITTI kit ship in
``tracker/profiles/``.

A detector's score also means different things at different ranges: far objects return few
points, so a true far box scores lower than a true near one (on KITTI, a low-scoring far
VirConv or SECOND-IoU car box is two to six times as likely to be real as a near one with the
same raw score; a far PointRCNN pedestrian less likely). Where the fit shows it, a class's map
carries a :class:`RangeTerm`, a logistic correction in range ``r`` (metres from the ego, over
``scale_m``) on the isotonic probability ``p₀``:  ``P = σ(a·logit p₀ + b·r + c·r² + d)``, with
``a > 0`` so the map stays monotone in the raw score, and ``r`` clipped to the range the fit
saw.

Without a profile ``mctrack kitti`` fits one without labels on the detections it tracks
(:func:`tracker.eval.calibrate.fit_self_profile`); a class it cannot fit, and any caller without
a profile, gets ``sigmoid(raw)`` (the BaseVersion convention for logits) or the raw value where
it already lies in [0, 1]: defensible for a detector that outputs calibrated probabilities or
logits, wrong for any other, so callers warn loudly (:func:`fallback_scores`).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from scipy.special import expit, logit

from tracker.boxes import FloatArray, IntArray
from tracker.categories import CATEGORIES, category_index
from tracker.config import toml_value
from tracker.errors import InputError
from tracker.frame import Frame

LOG = logging.getLogger(__name__)
PROFILE_DIR = Path(__file__).resolve().parent / "profiles"
PROFILE_VERSION = 2
READABLE_VERSIONS = (1, 2)  # version 1: no range terms
#: Probabilities are kept inside this range (the lifecycle's evidence -log(1 - p) stays finite).
PROB_RANGE = (0.001, 0.999)


def score_log_odds(score: FloatArray) -> FloatArray:
    """log(p / (1 - p)) of calibrated scores, p kept inside [1e-6, 1 - 1e-6] (NaN stays NaN):
    the unit of the track scores, offline (``offline.track_score_min``) and online
    (``lifecycle.track_score_min``)."""
    return logit(np.minimum(np.maximum(score, 1e-6), 1.0 - 1e-6))  # (np.clip: slower)


@dataclasses.dataclass(frozen=True, slots=True)
class RangeTerm:
    """``P = σ(logit_coef·logit p₀ + r_coef·r + r2_coef·r² + intercept)``, ``r`` = range over
    ``scale_m``, clipped to ``[min_m, max_m]`` (the fitted span: no quadratic extrapolation)."""

    logit_coef: float
    r_coef: float
    r2_coef: float
    intercept: float
    scale_m: float
    min_m: float
    max_m: float

    def __post_init__(self) -> None:
        values = (self.logit_coef, self.r_coef, self.r2_coef, self.intercept, self.scale_m,
                  self.min_m, self.max_m)  # fmt: skip
        if not all(math.isfinite(v) for v in values):
            raise ValueError("range term values must be finite")
        if self.logit_coef <= 0 or self.scale_m <= 0 or not 0 <= self.min_m <= self.max_m:
            raise ValueError("range term needs logit_coef > 0, scale_m > 0, 0 <= min_m <= max_m")

    def __call__(self, p0: FloatArray, range_m: FloatArray) -> FloatArray:
        r = np.clip(range_m, self.min_m, self.max_m) / self.scale_m
        z = (
            self.logit_coef * logit(np.clip(p0, *PROB_RANGE))
            + self.r_coef * r
            + self.r2_coef * r * r
        )
        return np.clip(expit(z + self.intercept), *PROB_RANGE)

    def as_dict(self) -> dict[str, float]:
        return {f.name: round(float(getattr(self, f.name)), 6) for f in dataclasses.fields(self)}


@dataclasses.dataclass(frozen=True, slots=True)
class ScoreMap:
    """One class's monotone map: ``np.interp`` through knots (raw increasing, prob
    non-decreasing in [0, 1]); constant beyond the first and last knot. With a ``range_term``
    and the boxes' ranges, the interpolated probability is corrected for range."""

    raw: FloatArray
    prob: FloatArray
    range_term: RangeTerm | None = None

    def __post_init__(self) -> None:
        raw, prob = np.asarray(self.raw, np.float64), np.asarray(self.prob, np.float64)
        ok = (
            raw.ndim == 1
            and raw.shape == prob.shape
            and len(raw) >= 1
            and bool(np.all(np.isfinite(raw)) and np.all(np.isfinite(prob)))
            and bool(np.all(np.diff(raw) > 0) and np.all(np.diff(prob) >= 0))
            and bool(np.all((prob >= 0) & (prob <= 1)))
        )
        if not ok:
            raise ValueError("a score map needs increasing raw knots and non-decreasing probs")
        object.__setattr__(self, "raw", raw)
        object.__setattr__(self, "prob", prob)

    def __call__(self, raw: FloatArray, range_m: FloatArray | None = None) -> FloatArray:
        p0 = np.interp(np.asarray(raw, np.float64), self.raw, self.prob)
        if self.range_term is None or range_m is None:
            return p0
        range_m = np.broadcast_to(np.asarray(range_m, np.float64), p0.shape)
        known = np.isfinite(range_m)  # unknown range: the range-free map
        return np.where(known, self.range_term(p0, np.where(known, range_m, 0.0)), p0)


@dataclasses.dataclass(frozen=True)
class ScoreProfile:
    """A detector's calibration: one :class:`ScoreMap` per class name, plus provenance.

    ``fitted_on`` says what data the maps come from (dataset, sequences, match rule) and
    ``quality`` the fit's quality per class (counts, Brier scores, calibration error); both
    are informative and kept verbatim.
    """

    detector: str
    maps: Mapping[str, ScoreMap]
    fitted_on: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    quality: Mapping[str, Mapping[str, Any]] = dataclasses.field(default_factory=dict)

    def scores(
        self,
        category: IntArray,
        raw: FloatArray,
        range_m: FloatArray | None = None,
        *,
        is_probability: bool | None = None,
    ) -> FloatArray:
        """Calibrated score per box (``range_m``: BEV distance from the ego, NaN or None where
        unknown); classes without a map keep :func:`fallback_scores` (``is_probability`` as
        there: decide it once for all the detector's boxes)."""
        raw = np.asarray(raw, np.float64)
        out = fallback_scores(raw, is_probability=is_probability)
        for name, score_map in self.maps.items():
            rows = np.asarray(category) == category_index(name)
            if rows.any():
                out[rows] = score_map(raw[rows], None if range_m is None else range_m[rows])
        return out


def box_ranges(frame: Frame) -> FloatArray:
    """BEV distance (m) of each box from the ego (NaN when the frame has no ego pose)."""
    ego = np.asarray(frame.world_from_ego, np.float64)[:2, 3]
    xyz = frame.boxes.xyz
    return np.hypot(xyz[:, 0] - ego[0], xyz[:, 1] - ego[1])


def fallback_scores(raw: FloatArray, *, is_probability: bool | None = None) -> FloatArray:
    """The uncalibrated score: the raw value when the raw scores are probabilities, else
    ``sigmoid(raw)`` (a logit). ``is_probability`` None: decided from ``raw`` (every finite
    value in [0, 1]); decide it once per detector, not per frame. NaN stays NaN."""
    raw = np.asarray(raw, np.float64)
    if is_probability is None:
        is_probability = looks_like_probability(raw)
    if is_probability:
        return raw.copy()
    with np.errstate(invalid="ignore"):  # a NaN (no raw score) is expected: no RuntimeWarning
        return np.exp(-np.logaddexp(0.0, -raw))


def looks_like_probability(raw: FloatArray) -> bool:
    finite = raw[np.isfinite(raw)]
    return bool(finite.size and finite.min() >= 0 and finite.max() <= 1)


def calibrate_frames(
    frames: Sequence[Frame], profile: ScoreProfile | None, *, is_probability: bool | None = None
) -> list[Frame]:
    """The frames with every box's ``score`` recomputed from ``score_raw`` by ``profile``
    (None: :func:`fallback_scores`). Boxes without a raw score keep their score. Where the
    fallback applies, ``is_probability`` None is decided once over all ``frames``."""
    if is_probability is None:
        every_raw = [f.boxes.score_raw for f in frames]
        is_probability = looks_like_probability(np.concatenate(every_raw)) if every_raw else False
    out = []
    for frame in frames:
        boxes = frame.boxes
        if len(boxes):
            raw = boxes.score_raw
            new = (
                profile.scores(
                    boxes.category, raw, box_ranges(frame), is_probability=is_probability
                )
                if profile
                else fallback_scores(raw, is_probability=is_probability)
            )
            boxes = boxes.replace(score=np.where(np.isfinite(raw), new, boxes.score))
        out.append(dataclasses.replace(frame, boxes=boxes))
    return out


#: share of a class's raw scores outside its map's knots above which a run warns: a profile
#: fitted on the detector's own scores leaves out under 0.02% of the kit's boxes (the three
#: shipped profiles on all 21 sequences), another detector's 14-56% (or none: a warning
#: needs scores beyond the knots, so the detector's name is checked too)
OUTSIDE_WARN = 0.01


def raw_outside_profile(profile: ScoreProfile, frames: Sequence[Frame]) -> dict[str, list[int]]:
    """Per class with a map: [boxes whose raw score lies outside the map's knots, boxes with a
    raw score]."""
    out: dict[str, list[int]] = {}
    for name, score_map in profile.maps.items():
        cat = category_index(name)
        raw = [f.boxes.score_raw[f.boxes.category == cat] for f in frames]
        raw = np.concatenate(raw) if raw else np.zeros(0)
        raw = raw[np.isfinite(raw)]
        outside = (raw < score_map.raw[0]) | (raw > score_map.raw[-1])
        out[name] = [int(outside.sum()), len(raw)]
    return out


def warn_other_detector(profile: ScoreProfile, detector: str) -> None:
    """Warn when ``profile`` was fitted for another detector than the run's."""
    if profile.detector != detector:
        LOG.warning(
            "score profile fitted for detector %r, used for %r: fit its own with `mctrack "
            "calibrate --detector %s`",
            profile.detector,
            detector,
            detector,
        )


def raw_scored_per_class(frames: Sequence[Frame]) -> dict[str, int]:
    """Boxes with a raw score (the ones a profile recalibrates), per class name."""
    counts = np.zeros(len(CATEGORIES), np.int64)
    for frame in frames:
        cat = frame.boxes.category
        known = np.isfinite(frame.boxes.score_raw) & (cat >= 0) & (cat < len(CATEGORIES))
        counts += np.bincount(cat[known], minlength=len(CATEGORIES))
    return {name: int(n) for name, n in zip(CATEGORIES, counts, strict=True) if n}


def warn_classes_without_map(
    profile: ScoreProfile, detector: str, boxes: Mapping[str, int], source: str
) -> None:
    """Warn, as loudly as a detector without a profile, for each class with boxes (``boxes``:
    count per class name, over a run) that ``profile`` (named ``source``) has no map for:
    their scores are the uncalibrated fallback, silently otherwise."""
    for name, n in boxes.items():
        if n and name not in profile.maps:
            LOG.warning(
                "NO SCORE CALIBRATION for the %s boxes of detector %r: profile %s has no "
                "[class.%s] map (its classes: %s), so the scores of these %d boxes are used as "
                "sigmoid(raw), or raw where already in [0, 1], and the tracker's thresholds may "
                "fit them less well. Fit a profile of that class on labelled sequences with "
                "`mctrack calibrate --detector %s --classes %s --out PROFILE.toml` and pass "
                "--profile PROFILE.toml.",
                name,
                detector,
                source,
                name,
                ", ".join(profile.maps) or "none",
                n,
                detector,
                name,
            )


def warn_scores_outside(
    profile: ScoreProfile, detector: str, outside: Mapping[str, Sequence[int]]
) -> None:
    """Warn for each class of which more than :data:`OUTSIDE_WARN` of the raw scores
    (``outside``: :func:`raw_outside_profile`, summed over a run) lie beyond the map's knots,
    where the map is flat: the thresholds then mean something else for those boxes."""
    for name, (n_out, n) in outside.items():
        if n and n_out > OUTSIDE_WARN * n:
            knots = profile.maps[name].raw  # (knots are written to 4 decimals: %g keeps them)
            LOG.warning(
                "%.0f%% of the %s scores of detector %r lie outside the profile's fitted range "
                "[%g, %g], where its map is flat: a profile fitted on few sequences, or "
                "another detector's? (`mctrack calibrate` on more labelled sequences)",
                100.0 * n_out / n,
                name,
                detector,
                knots[0],
                knots[-1],
            )


def resolve_profile(detector: str, path: str | Path | None = None) -> ScoreProfile | None:
    """The profile to calibrate ``detector``'s scores with: the file ``path`` when given, else
    the shipped one; None (with a loud warning: thresholds then mean something else for this
    detector) when there is none."""
    if path is not None:
        return profile_by_path_or_name(path)
    profile = find_profile(detector)
    if profile is None:
        LOG.warning(
            "NO SCORE CALIBRATION for detector %r: `mctrack kitti` and `mctrack robustness` "
            "calibrate its scores from the detections themselves (no labels; elsewhere they are "
            "used as sigmoid(raw), or raw where already in [0, 1]), so the tracker's thresholds "
            "may fit it less well. Fit a "
            "profile on labelled sequences with `mctrack calibrate --detector %s --out "
            "PROFILE.toml` and pass --profile PROFILE.toml (shipped profiles: %s).",
            detector,
            detector,
            ", ".join(builtin_profiles()),
        )
    return profile


def builtin_profiles() -> list[str]:
    """Detector names with a profile shipped in the package."""
    return sorted(p.stem for p in PROFILE_DIR.glob("*.toml"))


def find_profile(detector: str) -> ScoreProfile | None:
    """The shipped profile of ``detector`` (``tracker/profiles/<detector>.toml``), or None."""
    if detector in builtin_profiles():
        return load_profile(PROFILE_DIR / f"{detector}.toml")
    return None


def profile_by_path_or_name(value: str | Path) -> ScoreProfile:
    """The profile file ``value``, or where no such file exists, the shipped profile of that
    name (``--profile virconv``)."""
    if Path(value).exists():
        return load_profile(value)
    profile = find_profile(str(value))
    if profile is None:
        shipped = ", ".join(builtin_profiles())
        raise InputError(f"no such profile file, nor a shipped profile ({shipped})", path=value)
    return profile


#: the keys of a profile file, at the top and in each ``[class.<name>]`` table
PROFILE_KEYS = ("version", "detector", "fitted_on", "class")
CLASS_KEYS = ("raw", "prob", "range", "quality")


def _short(value: object) -> str:
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _is_number(value: object) -> bool:
    """A TOML integer or float (a bool is an int to Python; TOML integers have no size limit
    in tomllib, and one beyond a float's range is no number here)."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return False
    try:
        float(value)
    except OverflowError:
        return False
    return True


def _check_keys(table: Mapping[str, Any], allowed: Sequence[str], path: Path, where: str) -> None:
    """As the config loader: a key the format does not have (a typo) is an error, not a term
    silently left out."""
    for key in table:
        if key not in allowed:
            raise InputError(
                f"unknown key (expected {', '.join(allowed)})",
                path=path,
                field=f"{where}.{key}" if where else key,
            )


def _table(value: object, path: Path, field: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise InputError(f"expected a table, got {_short(value)}", path=path, field=field)
    return value


def _numbers(table: Mapping[str, Any], key: str, path: Path, where: str) -> FloatArray:
    """The array ``table[key]`` of numbers (TOML strings or booleans are not numbers)."""
    field = f"{where}.{key}"
    if key not in table:
        raise InputError("missing: expected an array of numbers", path=path, field=field)
    value = table[key]
    if not isinstance(value, list) or not value:
        raise InputError(
            f"expected a non-empty array of numbers, got {_short(value)}", path=path, field=field
        )
    for i, v in enumerate(value):
        if not _is_number(v):
            raise InputError(
                f"expected an array of numbers; element {i} is {_short(v)}", path=path, field=field
            )
    return np.array(value, dtype=np.float64)


def _range_term(value: object, path: Path, where: str) -> RangeTerm:
    term = _table(value, path, where)
    names = [f.name for f in dataclasses.fields(RangeTerm)]
    _check_keys(term, names, path, where)
    for name in names:
        if name not in term:
            raise InputError("missing: expected a number", path=path, field=f"{where}.{name}")
        if not _is_number(term[name]):
            raise InputError(
                f"expected a number, got {_short(term[name])}", path=path, field=f"{where}.{name}"
            )
    try:
        return RangeTerm(**{name: float(term[name]) for name in names})
    except ValueError:
        raise InputError(
            "expected finite numbers with logit_coef > 0, scale_m > 0, 0 <= min_m <= max_m",
            path=path,
            field=where,
        ) from None


def _score_map(table: Mapping[str, Any], path: Path, where: str) -> ScoreMap:
    raw = _numbers(table, "raw", path, where)
    prob = _numbers(table, "prob", path, where)
    if len(prob) != len(raw):
        raise InputError(
            f"{len(prob)} values, raw has {len(raw)}: one probability per knot",
            path=path,
            field=f"{where}.prob",
        )
    if not (np.all(np.isfinite(raw)) and np.all(np.diff(raw) > 0)):
        raise InputError(
            "expected finite, strictly increasing knots", path=path, field=f"{where}.raw"
        )
    if not (np.all((prob >= 0) & (prob <= 1)) and np.all(np.diff(prob) >= 0)):
        raise InputError(
            "expected non-decreasing probabilities in [0, 1]", path=path, field=f"{where}.prob"
        )
    term = _range_term(table["range"], path, f"{where}.range") if "range" in table else None
    return ScoreMap(raw, prob, term)


def load_profile(path: str | Path) -> ScoreProfile:
    """Read a profile file, as strictly as a config: an unknown key, a missing or mistyped
    value is one error naming the file and the dotted field."""
    path = Path(path)
    try:
        doc = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read profile: {exc}", path=path) from None
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"not valid TOML: {exc}", path=path) from None
    _check_keys(doc, PROFILE_KEYS, path, "")
    version = doc.get("version")
    if (
        not isinstance(version, int)
        or isinstance(version, bool)
        or version not in READABLE_VERSIONS
    ):
        expected = " or ".join(str(v) for v in READABLE_VERSIONS)
        raise InputError(
            f"expected version = {expected}, got {_short(version)}", path=path, field="version"
        )
    detector = doc.get("detector")
    if not isinstance(detector, str) or not detector:
        raise InputError(
            f"expected a detector name, got {_short(detector)}", path=path, field="detector"
        )
    fitted_on = _table(doc.get("fitted_on", {}), path, "fitted_on")
    classes = doc.get("class")
    if not isinstance(classes, dict) or not classes:
        raise InputError("expected [class.<name>] tables", path=path, field="class")
    maps: dict[str, ScoreMap] = {}
    quality: dict[str, dict[str, Any]] = {}
    for name, table in classes.items():
        where = f"class.{name}"
        if name not in CATEGORIES:
            raise InputError(f"unknown class {name!r}", path=path, field=where)
        table = _table(table, path, where)
        _check_keys(table, CLASS_KEYS, path, where)
        maps[name] = _score_map(table, path, where)
        quality[name] = dict(_table(table.get("quality", {}), path, f"{where}.quality"))
    return ScoreProfile(detector, maps, dict(fitted_on), quality)


def profile_toml(profile: ScoreProfile) -> str:
    """The profile as a small readable TOML document (what :func:`load_profile` reads)."""
    lines = [
        f"# Score calibration of the {profile.detector!r} detector: raw score -> probability",
        "# that the box is a real object (monotone, piecewise linear through the knots; where a",
        "# class has a range term, corrected for the box's distance from the ego).",
        "# Made by `mctrack calibrate` (or, without labels, by `mctrack kitti`'s",
        "# self-calibration); see tracker/calibration.py.",
        f"version = {PROFILE_VERSION}",
        f"detector = {toml_value(profile.detector)}",
        "",
        "[fitted_on]",
        *(f"{k} = {toml_value(v)}" for k, v in profile.fitted_on.items()),
    ]
    for name, score_map in profile.maps.items():
        lines += [
            "",
            f"[class.{name}]",
            f"raw = {toml_value([round(float(v), 4) for v in score_map.raw])}",
            f"prob = {toml_value([round(float(v), 4) for v in score_map.prob])}",
            *(
                [f"range = {toml_value(score_map.range_term.as_dict())}"]
                if score_map.range_term
                else []
            ),
            f"quality = {toml_value(dict(profile.quality.get(name, {})))}",
        ]
    return "\n".join(lines) + "\n"
