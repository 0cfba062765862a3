"""Tracker configuration: TOML files loaded into frozen dataclasses with strict validation.

File shape (see tracker/configs/kitti.toml)::

    dataset = "kitti"
    frame_rate_hz = 10.0
    categories = ["car", "pedestrian", "cyclist"]
    [defaults]            # every per-category key, once
    score_min = 0.4
    [defaults.bev]
    cost_max = 1.4
    [category.car]        # overrides only what differs
    score_min = 0.5

Unknown keys fail with their dotted path (``category.car.bev.cost_mx``); strings become enums
here, once, so the algorithm never compares strings.
"""

from __future__ import annotations

import copy
import enum
import logging
import math
import tomllib
import typing
from collections.abc import Callable, Mapping
from dataclasses import MISSING, dataclass, field, fields, is_dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from tracker.boxes import FloatArray
from tracker.categories import CATEGORIES, category_index
from tracker.errors import InputError

LOG = logging.getLogger(__name__)


class CostKind(enum.Enum):
    IOU = "iou"
    GIOU = "giou"
    DIOU = "diou"
    RO_GDIOU = "ro_gdiou"


class CostState(enum.Enum):
    """Which boxes the BEV cost compares (paper §3.2.2)."""

    PREDICT = "predict"  # the track predicted forward to the detection's time
    BACK_PREDICT = "back_predict"  # the detection moved back by its velocity to the track's time
    FUSION = "fusion"  # alpha * predict + (1 - alpha) * back_predict


class MotionModel(enum.Enum):
    CV = "cv"  # constant velocity [x, y, vx, vy]
    CA = "ca"  # constant acceleration [x, y, vx, vy, ax, ay] (the paper's model)


class ScoreSource(enum.Enum):
    """What the score thresholds compare against (tracker/calibration.py)."""

    PROFILE = "profile"  # P(true positive) from the detector's calibration profile
    AS_GIVEN = "as_given"  # the converted score (KITTI: sigmoid of the raw logit, the reference)


class TrackingMode(enum.Enum):
    ONLINE = "online"
    OFFLINE = "offline"


class OutputGeometry(enum.Enum):
    FILTERED = "filtered"  # Kalman position, size and heading
    DETECTION = "detection"  # a matched track reports its detection's box (velocity filtered)


class ImageBoxes(enum.Enum):
    """The 2D box written for a track matched this frame (KITTI's 2D protocol scores it)."""

    PROJECTION = "projection"  # the tracked 3D box's projection, always
    DETECTION = "detection"  # the matched detection's own 2D box
    # the detection's 2D box where it is its own, not its 3D box's projection (an image
    # head's), else the projection (tracker.io.writers.ImageBoxStats); a coasting track
    # carries its last own box along with its projection (tracker.io.writers.CarriedBoxes)
    AUTO = "auto"


class GreedyOrder(enum.Enum):
    DETECTION = "detection"  # the reference: detections in index order take their best track
    COST = "cost"  # globally cheapest pair first


@dataclass(frozen=True, slots=True)
class KalmanNoise:
    """Diagonal variances: initial covariance P0, process noise Q (per nominal frame), noise R."""

    p: tuple[float, ...]
    q: tuple[float, ...]
    r: tuple[float, ...]


@dataclass(frozen=True, slots=True)
class BevConfig:
    cost: CostKind = CostKind.RO_GDIOU
    w1: float = 1.0  # Ro_GDIoU weight of (C - U) / C
    w2: float = 1.0  # Ro_GDIoU weight of c² / d²
    cost_state: CostState = CostState.PREDICT
    alpha: float = 0.5  # FUSION blend weight of the forward prediction
    cost_max: float = 1.4  # accept a pair iff 1 - similarity <= cost_max
    gate_distance_m: float = 10.0  # pairs farther apart than this (BEV centres) are not scored
    # the gate follows the detections' noise: once the scene's centre noise σ (per axis,
    # tracker/noise.py) is estimated, pairs farther apart than √(gate_motion_m² + (4σ)²) are not
    # scored either: the detection's own error (4σ: 99.97 % of it) plus how far the object moves
    # from where its track predicts it (m). inf: off
    gate_motion_m: float = math.inf
    # buffered boxes (BIoU, Yang et al. 2023): the cost compares boxes whose length and width
    # are grown by this fraction on each side (l(1 + 2b)), so that centre noise comparable to a
    # small object's size still leaves overlap to score; 0 = the boxes as they are
    buffer: float = 0.0


@dataclass(frozen=True, slots=True)
class RvConfig:
    cost_max: float = -0.3  # accept iff 1 - SDIoU <= cost_max
    yaw_gate_deg: float = 90.0
    distance_gate_m: float = 5.0


@dataclass(frozen=True, slots=True)
class LifecycleConfig:
    min_hits: int = 1  # hits before a track is confirmed and output (1 = at birth)
    confirm_score: float = 2.0  # a detection scoring >= this confirms at once (2 = never)
    # confirm when the hits' evidence 1 - prod(1 - score) reaches this (1 = never): with
    # calibrated scores, the probability that at least one of them was a real object
    confirm_prob: float = 1.0
    max_misses_tentative: int = 0  # misses after which an unconfirmed track is deleted
    max_misses_output: int = 0  # consecutive misses during which a coasting track is still output
    # a missed track coasts (is output) only once it has this many hits: a track confirmed by one
    # confident box and then missed is most likely a one-frame false positive (1: any track)
    coast_min_hits: int = 1
    max_misses: int = 30  # consecutive misses after which a track is deleted
    # online: a live track is output only while the mean log-odds of its hits' scores reaches
    # this (0: more likely real than not; -inf: off, "-inf" in JSON). The track-level analogue of
    # offline.track_score_min: a persistent false positive gathers noisy-OR evidence from many
    # weak hits (its errors are correlated across frames), its mean stays low
    track_score_min: float = -np.inf
    # offline: a whole track of this class is kept only if the mean log-odds of its hits' scores
    # also exceeds this (on top of offline.track_score_min; -inf: that value alone)
    offline_track_score_min: float = -np.inf


@dataclass(frozen=True, slots=True)
class PoseFilterConfig:
    motion: MotionModel = MotionModel.CV
    measure_velocity: bool = False  # use the detector's velocity as a measurement (nuScenes)
    cv: KalmanNoise = KalmanNoise((1, 1, 500, 500), (0.5, 0.5, 5, 5), (0.1, 0.1))
    ca: KalmanNoise = KalmanNoise((1, 1, 500, 500, 100, 100), (0.5, 0.5, 5, 5, 1, 1), (0.1, 0.1))
    # > 0: the position measurement variance is r_scale × the detections' own centre variance,
    # estimated per scene as it runs (tracker.noise); the model's r until the estimate exists.
    # 0: the model's fixed r (the reference)
    r_scale: float = 0.0


@dataclass(frozen=True, slots=True)
class HeadingFilterConfig:
    noise: KalmanNoise = KalmanNoise((0.1, 0.1), (0.1, 0.1), (0.2, 5.0))  # r: (det, velocity)
    min_speed_mps: float = 2.0  # below this the velocity direction is noise: not used


@dataclass(frozen=True, slots=True)
class CategoryConfig:
    score_min: float = 0.0  # detections with score <= this are dropped (strict >, as the reference)
    birth_score_min: float = 0.0  # only detections scoring above this start tracks
    nms_iou_max: float = 1.0  # class-aware BEV NMS; 1.0 disables it for this category
    bev: BevConfig = BevConfig()
    rv: RvConfig = RvConfig()
    lifecycle: LifecycleConfig = LifecycleConfig()
    pose: PoseFilterConfig = PoseFilterConfig()
    size: KalmanNoise = KalmanNoise((1, 1, 10, 10), (0.5, 0.5, 1.5, 1.5), (0.02, 0.02))
    heading: HeadingFilterConfig = HeadingFilterConfig()
    # the 2D image box written for 2D-box evaluation (KITTI) is the projected 3D box with its
    # width scaled by this: a pedestrian's annotated 2D box is narrower than its cuboid's
    # projection (median 1/1.49 even for ground-truth boxes: bench/kitti_box_shapes.py)
    image_width_scale: float = 1.0
    # z and height (no Kalman axis of their own): each hit moves the track's values this fraction
    # of the way to its detection's, an exponential smoother (1 = the detection's own, the
    # reference)
    vertical_gain: float = 1.0


@dataclass(frozen=True, slots=True)
class OfflineConfig:
    track_score_min: float = 1.4  # a track is kept iff its mean detection logit > this
    interpolate_max_gap: int = 30  # interior gaps up to this many frames are filled
    # offline only: each track's positions smoothed by a centred local quadratic fit over this
    # many seconds (Savitzky-Golay; 0 = off): no filter lag, and the box noise averages out
    smooth_seconds: float = 0.0
    # offline only: x, y of each detected row from the RTS smoother (the online pose filter over
    # the track's detections, then its backward pass: tracker.smoothing), instead of the online
    # filter's estimate, which lags behind a moving object
    rts: bool = False
    # the position smoother's measurement variance: this multiple of the online filter's r. The
    # online r (pose.r_scale x the detections' frame-to-frame noise) does not see the part of a
    # box's error that persists over frames, which a smoother averaging a whole track can take
    rts_r_multiple: float = 1.0
    # offline only: the heading of each detected row from the RTS smoother of the heading filter
    # over the track's detected yaws (tracker.smoothing.rts_smooth_heading), instead of the
    # online filter's, which follows each box's yaw error
    rts_heading: bool = False
    # offline only: each track gets one size, the mean of its detected rows' (filtered) sizes
    constant_size: bool = False
    # offline only: a kept track that starts at most this many frames after another of its class
    # ended, where that one's constant-velocity extrapolation puts it (within stitch_distance_m),
    # continues it under its id (one-to-one, Hungarian on the distance; 0 = off)
    stitch_max_gap: int = 0
    stitch_distance_m: float = 1.0
    # offline only: two neighbouring tracks that exchanged objects get their tails back where,
    # over this many seconds either side, the difference of their detections is far likelier
    # with the tails exchanged (tracker.exchange; 0 = off)
    exchange_seconds: float = 0.0
    # offline only: a track's written own 2D boxes (an image head's, not projections; see
    # image_boxes) keep their offset from its projection averaged over smooth_seconds, and its
    # coasting rows carry that average (tracker.io.writers.smooth_own_boxes)
    smooth_image_boxes: bool = False


@dataclass(frozen=True, slots=True)
class TrackerConfig:
    dataset: str
    frame_rate_hz: float
    categories: tuple[str, ...]
    per_category: dict[str, CategoryConfig]
    mode: TrackingMode = TrackingMode.ONLINE
    rv_matching: bool = True
    rv_reference: bool = False  # reference stage 2: stale 2D boxes, gated detections dropped
    greedy_order: GreedyOrder = GreedyOrder.DETECTION
    nms: bool = False
    output_geometry: OutputGeometry = OutputGeometry.FILTERED
    image_boxes: ImageBoxes = ImageBoxes.PROJECTION
    # Where detections exist only inside the camera images (KITTI), a coasting track is output
    # only while at least this fraction of its projected box's width is inside an image: a track
    # leaving the view has an explained miss, not a dropped box (0 = always output)
    coast_min_in_view: float = 0.0
    # a detection with a 2D box of its own (an image head's) has its 3D centre turned toward that
    # box's bearing, by the weight the two sources' estimated noise gives (tracker.fusion)
    image_bearing: bool = False
    offline: OfflineConfig = OfflineConfig()
    scores: ScoreSource = ScoreSource.AS_GIVEN
    source: str = "<defaults>"
    category_ids: tuple[int, ...] = field(default=())

    def __post_init__(self) -> None:
        object.__setattr__(self, "category_ids", tuple(category_index(c) for c in self.categories))

    @property
    def nominal_dt_secs(self) -> float:
        return 1.0 / self.frame_rate_hz

    @property
    def offline_smooth_frames(self) -> int:
        """``offline.smooth_seconds`` in frames, odd (a window centred on each frame)."""
        return round(self.offline.smooth_seconds * self.frame_rate_hz) | 1

    def kitti_writer_options(self) -> dict[str, Any]:
        """The keywords of :func:`tracker.io.writers.write_kitti_sequence` this config sets."""
        window = 0
        if self.mode is TrackingMode.OFFLINE and self.offline.smooth_image_boxes:
            window = self.offline_smooth_frames
        return {
            "image_boxes": self.image_boxes,
            "width_scale": self.image_width_scales(),
            "own_box_window": window,
        }

    def image_width_scales(self) -> FloatArray:
        """``image_width_scale`` per global category index (1 where not tracked)."""
        return np.nan_to_num(self.per_category_array(lambda c: c.image_width_scale), nan=1.0)

    def per_category_array(self, getter: typing.Callable[[CategoryConfig], float]) -> FloatArray:
        """A value per global category index (NaN where not tracked), for vectorised use."""
        out = np.full(len(CATEGORIES), np.nan)
        for name, cfg in self.per_category.items():
            out[category_index(name)] = getter(cfg)
        return out


# ---------------------------------------------------------------------------------------------
# loading

BUILTIN = ("kitti", "kitti_offline", "kitti_reference", "nuscenes", "waymo")


def load_config(
    name_or_path: str | Path, *, overrides: dict[str, Any] | None = None
) -> TrackerConfig:
    """Load a built-in config by name (see ``BUILTIN``) or a TOML file by path.

    ``overrides`` is a nested dict merged over the file (used by tuning scripts and tests).

    A config whose mode is offline (its own ``mode``, or ``overrides["mode"]``, which is how
    every command's ``--mode`` reaches it) is its offline variant: each built-in in its ``base``
    chain that has one (``kitti`` -> ``kitti_offline``) is replaced by it, unless the chain
    holds it already. So ``kitti`` in offline mode is ``kitti_offline``, and a file on ``kitti``
    gets ``kitti_offline``'s offline settings wherever it sets none of its own. A file with no
    such built-in under it keeps its own ``[offline]`` table (both logged once per file).

    Symmetrically, a config whose mode is online runs each built-in offline variant in its
    chain as its base (``kitti_offline`` -> ``kitti``): the variant's settings are for offline
    mode (kitti_offline's pedestrians survive a missed frame unconfirmed), so ``kitti_offline``
    in online mode is ``kitti`` (a warning, once per config, says so).
    """
    raw, source, chain = _load_raw(name_or_path, seen=())
    over = _canonical_categories(overrides or {}, source)
    raw = _merge(raw, over)
    mode = raw.get("mode", TrackingMode.ONLINE.value)
    if mode == TrackingMode.OFFLINE.value:
        offline_raw, source, offline_chain = _load_raw(name_or_path, seen=(), mode=mode)
        if offline_chain != chain:
            raw = _merge(offline_raw, over)
        if str(name_or_path) not in BUILTIN:
            _note_offline(source, chain, offline_chain)
    elif mode == TrackingMode.ONLINE.value and any(online_base(name) for name in chain):
        _note_online(source, chain)
        online_raw, source, _ = _load_raw(name_or_path, seen=(), mode=mode)
        raw = _merge(online_raw, over)
    return config_from_dict(raw, source=source)


def offline_variant(name: str | Path) -> str | None:
    """The built-in offline variant of a built-in config name (``kitti`` -> ``kitti_offline``),
    or None."""
    variant = f"{name}_offline"
    return variant if str(name) in BUILTIN and variant in BUILTIN else None


def online_base(name: str | Path) -> str | None:
    """The built-in whose offline variant a built-in config name is (``kitti_offline`` ->
    ``kitti``), or None."""
    return next((base for base in BUILTIN if offline_variant(base) == str(name)), None)


def config_for_mode(name_or_path: str | Path, mode: str | None) -> str | Path:
    """The config a run in ``mode`` loads, as commands name it (summaries, tune records): in
    offline mode a built-in's offline variant where it has one, in online mode a built-in
    offline variant's base (said once), else the config itself (a file's variant is resolved by
    :func:`load_config`, under its own name)."""
    if mode == TrackingMode.OFFLINE.value:
        return offline_variant(name_or_path) or name_or_path
    base = online_base(name_or_path) if mode == TrackingMode.ONLINE.value else None
    if base is not None:
        _note_online(f"<builtin {name_or_path}>", (str(name_or_path), base))
        return base
    return name_or_path


_NOTED: set[str] = set()


def _note_offline(source: str, chain: tuple[str, ...], offline_chain: tuple[str, ...]) -> None:
    """Say once per file which offline settings a custom config runs with."""
    if source in _NOTED:
        return
    _NOTED.add(source)
    swapped = [(a, b) for a, b in zip(chain, offline_chain, strict=False) if a != b]
    if swapped:
        (base, variant), *_ = swapped
        LOG.info(
            "%s, offline mode: on %s (the offline variant of its base %s) where it sets no value "
            "of its own",
            source, variant, base,
        )  # fmt: skip
    elif not any(name.endswith("_offline") and name in BUILTIN for name in chain):
        LOG.info(
            "%s, offline mode: no built-in offline variant under it (%s); its own [offline] "
            "settings, defaults where unset",
            source, " -> ".join(chain),
        )  # fmt: skip


def _note_online(source: str, chain: tuple[str, ...]) -> None:
    """Say once per config that the offline variant in its chain runs as its online base."""
    key = f"online {source}"
    if key in _NOTED:
        return
    _NOTED.add(key)
    variant = next(name for name in chain if online_base(name))
    base = online_base(variant)
    if source == f"<builtin {variant}>":
        LOG.warning(
            "config %s, online mode: runs its base %s (%s's settings are for offline mode: "
            "--mode offline runs them)",
            variant, base, variant,
        )  # fmt: skip
    else:
        LOG.warning(
            "%s, online mode: on %s instead of %s (its offline variant, in the base chain) where "
            "it sets no value of its own; %s's settings are for offline mode (--mode offline)",
            source, base, variant, variant,
        )  # fmt: skip


def _load_raw(
    name_or_path: str | Path, *, seen: tuple[str, ...], mode: str | None = None
) -> tuple[dict[str, Any], str, tuple[str, ...]]:
    """The TOML table, with ``base = "<name or path>"`` resolved (the file overrides its base),
    its source and the chain of configs it was built from (outermost first). ``mode``
    offline: each built-in with an offline variant not already in the chain is replaced by it;
    online: each built-in offline variant by its base."""
    variant = None
    if mode == TrackingMode.OFFLINE.value:
        variant = offline_variant(name_or_path)
    elif mode == TrackingMode.ONLINE.value:
        variant = online_base(name_or_path)
    if variant is not None and f"<builtin {variant}>" not in seen:
        name_or_path = variant
    text, source = _read_source(name_or_path)
    if source in seen:
        raise InputError(f"{source}: 'base' chain loops: {' -> '.join((*seen, source))}")
    try:
        raw = _canonical_categories(tomllib.loads(text), source)
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{source}: malformed TOML ({exc})") from None
    base = raw.pop("base", None)
    if base is None:
        return raw, source, (str(name_or_path),)
    if not isinstance(base, str):
        raise InputError(f"{source}: 'base' must be a config name or path")
    written = base
    if base not in BUILTIN and not Path(base).is_absolute() and str(name_or_path) not in BUILTIN:
        base = str(Path(name_or_path).parent / base)  # relative to the file
    if base not in BUILTIN and not Path(base).is_file():  # named by the file that asks for it
        where = "" if base == written else f" (resolved to {base})"
        raise InputError(
            f"{source}: base {written!r}{where}: config not found (built-in names: "
            f"{', '.join(BUILTIN)})"
        )
    base_raw, _, chain = _load_raw(base, seen=(*seen, source), mode=mode)
    return _merge(base_raw, raw), source, (str(name_or_path), *chain)


def _read_source(name_or_path: str | Path) -> tuple[str, str]:
    if str(name_or_path) in BUILTIN:
        res = resources.files("tracker") / "configs" / f"{name_or_path}.toml"
        return res.read_text(), f"<builtin {name_or_path}>"
    path = Path(name_or_path)
    if not path.is_file():
        raise InputError(f"{path}: config not found (built-in names: {', '.join(BUILTIN)})")
    try:
        return path.read_text(encoding="utf-8"), str(path)
    except UnicodeDecodeError as exc:  # (the decoder's message names no file)
        why = f"not a UTF-8 text file (byte {exc.start}: {exc.reason})"
        raise InputError(f"{path}: {why}") from None


def _merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = copy.deepcopy(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value)
        else:
            out[key] = value
    return out


def _canonical_categories(raw: dict[str, Any], source: str) -> dict[str, Any]:
    """``raw`` with ``categories`` and the ``[category.<name>]`` sections under their canonical
    names (case and known spellings as :func:`category_index` reads them, as ``--classes``
    does): ``[category.Car]`` is car's section, merged over a base's ``[category.car]``. A
    category named twice in one table is refused (which section would win is not obvious)."""
    out = dict(raw)
    categories = raw.get("categories")
    if isinstance(categories, list):
        names: list[str] = []
        for name in categories:
            index = category_index(name) if isinstance(name, str) else -1
            if index < 0:
                raise InputError(f"{source}: categories: unknown category {name!r}")
            if CATEGORIES[index] in names:
                raise InputError(
                    f"{source}: categories: {name!r} names {CATEGORIES[index]!r} a second time"
                )
            names.append(CATEGORIES[index])
        out["categories"] = names
    sections = raw.get("category")
    if isinstance(sections, dict):
        canonical: dict[str, Any] = {}
        written: dict[str, str] = {}
        for name, table in sections.items():
            index = category_index(name)
            if index < 0:
                raise InputError(f"{source}: category.{name}: unknown category")
            key = CATEGORIES[index]
            if key in canonical:
                raise InputError(
                    f"{source}: category.{name}: the same category as category.{written[key]} "
                    "(one section per category)"
                )
            if not isinstance(table, dict):
                raise InputError(f"{source}: category.{name}: expected a table, got {table!r}")
            canonical[key], written[key] = table, name
        out["category"] = canonical
    return out


def config_from_dict(raw: dict[str, Any], *, source: str = "<dict>") -> TrackerConfig:
    raw = _canonical_categories(raw, source)
    defaults = raw.pop("defaults", {})
    per_cat_raw = raw.pop("category", {})
    categories = raw.get("categories")
    if not isinstance(categories, list) or not categories:
        raise InputError(f"{source}: 'categories' must be a non-empty list of names")
    if not isinstance(per_cat_raw, dict):
        raise InputError(f"{source}: category: expected a table, got {per_cat_raw!r}")
    _check_ranges(_build(CategoryConfig, defaults, "defaults", source), "defaults", source)
    # every section is validated (typos fail even when that category is not tracked in this
    # run); the tracked categories are kept
    sections = {
        name: _build(
            CategoryConfig, _merge(defaults, per_cat_raw.get(name, {})), f"category.{name}", source
        )
        for name in sorted(set(categories) | set(per_cat_raw))
    }
    per_category = {name: sections[name] for name in categories}
    top = _build(
        TrackerConfig,
        {**raw, "categories": tuple(categories), "per_category": per_category, "source": source},
        "",
        source,
        skip={"per_category", "source"},
    )
    _check_ranges(top, "", source)
    for name, cfg in sections.items():
        _check_ranges(cfg, f"category.{name}", source)
    return top


# a Kalman noise's variances: finite and >= 0, the measurement's > 0 (tracker.kalman.DiagonalNoise)
_NOISE_CHECKS: tuple[tuple[str, Callable[[Any], bool], str], ...] = (
    ("p", lambda v: all(0.0 <= x < math.inf for x in v), "must be finite variances >= 0"),
    ("q", lambda v: all(0.0 <= x < math.inf for x in v), "must be finite variances >= 0"),
    ("r", lambda v: all(0.0 < x < math.inf for x in v), "must be finite variances > 0"),
)
_COUNT = (lambda v: v >= 0, "must be >= 0")
_PROBABILITY = (lambda v: 0.0 <= v <= 1.0, "must be in [0, 1] (a probability)")
_LOG_ODDS = (lambda v: v < math.inf, "must be a log-odds < inf (-inf: off)")
#: Each numeric setting's range, by dotted key, checked once the config is built (NaN fails
#: every check, and _coerce refuses it first). Scores are probabilities whatever ``scores`` says
#: (a detection's score is in [0, 1]: calibrated, sigmoid(raw), or a BaseVersion
#: detection_score); confirm_score 2 is documented as "never", so it is not capped at 1.
_RANGES: dict[type, tuple[tuple[str, Callable[[Any], bool], str], ...]] = {
    TrackerConfig: (
        ("frame_rate_hz", lambda v: 0.0 < v < math.inf, "must be finite and > 0"),
        ("coast_min_in_view", lambda v: 0.0 <= v <= 1.0, "must be in [0, 1]"),
    ),
    OfflineConfig: (
        ("track_score_min", *_LOG_ODDS),
        ("interpolate_max_gap", *_COUNT),
        ("smooth_seconds", lambda v: 0.0 <= v < math.inf, "must be finite and >= 0"),
        ("rts_r_multiple", lambda v: 0.0 < v < math.inf, "must be finite and > 0"),
        ("stitch_max_gap", *_COUNT),
        ("stitch_distance_m", lambda v: 0.0 <= v < math.inf, "must be finite and >= 0"),
        ("exchange_seconds", lambda v: 0.0 <= v < math.inf, "must be finite and >= 0"),
    ),
    CategoryConfig: (
        ("score_min", *_PROBABILITY),
        ("birth_score_min", *_PROBABILITY),
        ("nms_iou_max", lambda v: 0.0 <= v <= 1.0, "must be in [0, 1] (an IoU)"),
        ("image_width_scale", lambda v: 0.0 < v <= 1.0, "must be in (0, 1]"),
        ("vertical_gain", lambda v: 0.0 < v <= 1.0, "must be in (0, 1]"),
    ),
    BevConfig: (
        ("w1", lambda v: abs(v) < math.inf, "must be finite"),
        ("w2", lambda v: abs(v) < math.inf, "must be finite"),
        ("alpha", lambda v: 0.0 <= v <= 1.0, "must be in [0, 1]"),
        ("gate_distance_m", lambda v: v > 0.0, "must be > 0 (inf: off)"),
        ("gate_motion_m", lambda v: v > 0.0, "must be > 0 (inf: off)"),
        ("buffer", lambda v: 0.0 <= v <= 2.0, "must be in [0, 2]"),
    ),
    RvConfig: (
        ("yaw_gate_deg", lambda v: v >= 0.0, "must be >= 0"),
        ("distance_gate_m", lambda v: v >= 0.0, "must be >= 0"),
    ),
    LifecycleConfig: (
        ("min_hits", *_COUNT),
        ("confirm_score", lambda v: v >= 0.0, "must be >= 0 (above 1: never)"),
        ("confirm_prob", lambda v: 0.0 <= v <= 1.0, "must be in [0, 1] (1: never)"),
        ("max_misses_tentative", *_COUNT),
        ("max_misses_output", *_COUNT),
        ("coast_min_hits", *_COUNT),
        ("max_misses", *_COUNT),
        ("track_score_min", *_LOG_ODDS),
        ("offline_track_score_min", *_LOG_ODDS),
    ),
    PoseFilterConfig: (("r_scale", lambda v: 0.0 <= v < math.inf, "must be finite and >= 0"),),
    HeadingFilterConfig: (("min_speed_mps", lambda v: v >= 0.0, "must be >= 0"),),
    KalmanNoise: _NOISE_CHECKS,
}


def range_error(table: Any, name: str, value: Any) -> str | None:
    """What setting ``name`` of the config table ``table`` (a :class:`BevConfig`, say) must be
    ("must be in [0, 2]", as a config file's error says it) when ``value`` is outside its range;
    None when it is inside, or the setting has no range."""
    for key, ok, what in _RANGES.get(type(table), ()):
        if key == name and not ok(value):
            return what
    return None


def _noise_lengths(obj: Any) -> dict[str, tuple[tuple[int, ...], ...]]:
    """The allowed (p, q, r) lengths of ``obj``'s Kalman noises, by field: the state's
    dimension and the measurement's. A pose's r is [x, y], or [x, y, vx, vy] for a detector's
    velocity (with 2 the velocity, where measured, gets a placeholder: tracker.kalman)."""
    if isinstance(obj, PoseFilterConfig):  # (the model in use; the other's noise is unread)
        n = 4 if obj.motion is MotionModel.CV else 6
        return {obj.motion.value: ((n,), (n,), (2, 4))}
    if isinstance(obj, CategoryConfig):
        return {"size": ((4,), (4,), (2,))}
    if isinstance(obj, HeadingFilterConfig):
        return {"noise": ((2,), (2,), (2,))}
    return {}


def _check_ranges(obj: Any, path: str, source: str) -> None:
    """Every setting of ``obj`` (and of its nested tables) inside its range, else the one-line
    error naming the file and the dotted key."""
    for key, ok, what in _RANGES.get(type(obj), ()):
        if not ok(getattr(obj, key)):
            dotted = f"{path}.{key}" if path else key
            raise InputError(f"{source}: {dotted} {what}, got {toml_value(getattr(obj, key))}")
    for name, lengths in _noise_lengths(obj).items():
        noise = getattr(obj, name)
        for key, allowed in zip(("p", "q", "r"), lengths, strict=True):
            if len(getattr(noise, key)) not in allowed:
                dotted = f"{path}.{name}.{key}" if path else f"{name}.{key}"
                raise InputError(
                    f"{source}: {dotted} needs {' or '.join(map(str, allowed))} values (one per "
                    f"axis), got {toml_value(getattr(noise, key))}"
                )
    for f in fields(obj):
        value = getattr(obj, f.name)
        if is_dataclass(value) and f.name != "per_category":
            _check_ranges(value, f"{path}.{f.name}" if path else f.name, source)


def _build(
    cls: type,
    raw: Any,
    path: str,
    source: str,
    *,
    base: Any = None,
    skip: set[str] | None = None,
) -> Any:
    """A dataclass from a table; absent keys come from ``base`` (or the field default)."""
    if not isinstance(raw, dict):
        raise InputError(f"{source}: {path or '<top>'}: expected a table, got {raw!r}")
    names = {f.name for f in fields(cls)} - {"category_ids"}
    for key in raw:
        if key not in names:
            raise InputError(f"{source}: unknown key '{path + '.' if path else ''}{key}'")
    hints = typing.get_type_hints(cls)
    kwargs: dict[str, Any] = {}
    for f in fields(cls):
        if f.name not in raw:
            if base is not None:
                kwargs[f.name] = getattr(base, f.name)
            continue
        if skip and f.name in skip:
            kwargs[f.name] = raw[f.name]
            continue
        dotted = f"{path}.{f.name}" if path else f.name
        nested_base = getattr(base, f.name) if base is not None else f.default
        if nested_base is MISSING:
            nested_base = None
        kwargs[f.name] = _coerce(hints[f.name], raw[f.name], dotted, source, nested_base)
    try:
        return cls(**kwargs)
    except TypeError as exc:
        raise InputError(f"{source}: {path or '<top>'}: {exc}") from None


def _coerce(tp: Any, value: Any, dotted: str, source: str, base: Any = None) -> Any:
    if isinstance(tp, type) and is_dataclass(tp):
        return _build(tp, value, dotted, source, base=base)
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        try:
            return tp(value)
        except ValueError:
            allowed = ", ".join(repr(m.value) for m in tp)
            raise InputError(f"{source}: {dotted}: {value!r} is not one of {allowed}") from None
    if typing.get_origin(tp) is tuple:
        if not isinstance(value, list | tuple):
            raise InputError(f"{source}: {dotted}: expected a list, got {value!r}")
        item_tp = typing.get_args(tp)[0]
        return tuple(_coerce(item_tp, v, f"{dotted}[{i}]", source) for i, v in enumerate(value))
    checks: dict[Any, tuple[Any, str]] = {
        bool: (bool, "true/false"),
        int: (int, "an integer"),
        float: (int | float, "a number"),
        str: (str, "a string"),
    }
    if tp is float and value in ("inf", "-inf"):  # how config_to_dict writes an infinity
        return float(value)
    if tp in checks:
        allowed_types, what = checks[tp]
        if (tp is not bool and isinstance(value, bool)) or not isinstance(value, allowed_types):
            raise InputError(f"{source}: {dotted}: expected {what}, got {value!r}")
        if tp is float and math.isnan(value):
            raise InputError(f"{source}: {dotted}: expected a number, got nan")
        return float(value) if tp is float else value
    return value


def config_to_dict(cfg: Any) -> Any:
    """Resolved config as plain data (for summaries and the recording's config document).

    A :class:`TrackerConfig` gives the layout :func:`config_from_dict` reads (its categories
    under ``category``, every value resolved, no ``defaults``), so a run's summary reloads into
    the same config.
    """
    if isinstance(cfg, TrackerConfig):
        out = {
            f.name: config_to_dict(getattr(cfg, f.name))
            for f in fields(cfg)
            if f.name not in ("per_category", "category_ids")  # (category_ids is derived)
        }
        out["category"] = config_to_dict(cfg.per_category)
        return out
    if is_dataclass(cfg):
        return {f.name: config_to_dict(getattr(cfg, f.name)) for f in fields(cfg)}
    if isinstance(cfg, enum.Enum):
        return cfg.value
    if isinstance(cfg, dict):
        return {k: config_to_dict(v) for k, v in cfg.items()}
    if isinstance(cfg, tuple | list):
        return [config_to_dict(v) for v in cfg]
    if isinstance(cfg, float) and np.isinf(cfg):
        return str(cfg)  # JSON has no infinity: "-inf" / "inf", read back by _coerce
    return cfg


def toml_value(value: Any, *, decimals: int | None = 6) -> str:
    """A TOML value (number, string, bool, list or inline table); floats rounded to
    ``decimals`` (None: exactly, as Python's shortest repr)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if not math.isfinite(value):
            return "nan" if math.isnan(value) else ("inf" if value > 0 else "-inf")
        return repr(value if decimals is None else round(value, decimals))
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, Mapping):
        items = (f"{k} = {toml_value(v, decimals=decimals)}" for k, v in value.items())
        return "{ " + ", ".join(items) + " }"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v, decimals=decimals) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")
