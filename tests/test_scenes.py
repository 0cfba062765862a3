"""Scene-parallel runs (app/scenes.py): byte-identical outputs, in order, with --workers and
--ray; a scene with bad input fails alone; a task whose worker dies is run again."""

from __future__ import annotations

import json
import os
import shutil
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import pytest

from app import scenes
from app.cli import main
from app.common import score_source
from app.kitti import KittiSceneJob, run_kitti
from tracker.config import load_config
from tracker.io.baseversion import write_baseversion
from tracker.io.nuscenes_writer import (
    nuscenes_results,
    write_nuscenes_parts,
    write_nuscenes_results,
)
from tracker.io.synthetic import synthetic_scene
from tracker.io.writers import tracks_scene_json, write_tracks_file, write_tracks_parts
from tracker.pipeline import run_scene

ROOT = Path(__file__).resolve().parents[1]
SAMPLE_KIT = ROOT / "sample_data" / "kitti-0001" / "raw"
CLASSES = ("Car", "Pedestrian", "Cyclist")


def _copy_seq(kit: Path, new: str, n_frames: int) -> None:
    """Sequence ``new`` = the sample's first ``n_frames`` frames (its own length and content)."""

    def keep(path: Path, out: Path, sep: str | None) -> None:
        lines = path.read_text().splitlines(keepends=True)
        kept = [ln for ln in lines if int(ln.split(sep)[0]) < n_frames]
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text("".join(kept))

    train = SAMPLE_KIT / "training"
    shutil.copy(train / "calib" / "0001.txt", kit / "training" / "calib" / f"{new}.txt")
    poses = (train / "pose_orbslam3" / "0001.txt").read_text().splitlines(keepends=True)
    (kit / "training" / "pose_orbslam3" / f"{new}.txt").write_text("".join(poses[:n_frames]))
    keep(train / "label_02" / "0001.txt", kit / "training" / "label_02" / f"{new}.txt", None)
    for cls in CLASSES:
        det = SAMPLE_KIT / "detections" / "pointrcnn" / "training" / cls / "0001.txt"
        keep(det, kit / "detections" / "pointrcnn" / "training" / cls / f"{new}.txt", ",")


@pytest.fixture(scope="module")
def small_kit(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A three-sequence kit made from the sample: 0001 (447 frames), 0002 (60), 0003 (120)."""
    kit = tmp_path_factory.mktemp("kit")
    shutil.copytree(SAMPLE_KIT, kit, dirs_exist_ok=True)
    _copy_seq(kit, "0002", 60)
    _copy_seq(kit, "0003", 120)
    return kit


def _files(out: Path) -> dict[str, bytes]:
    """Every result file of a run (the summary holds timings, so it is compared separately)."""
    return {
        str(p.relative_to(out)): p.read_bytes()
        for p in sorted(out.rglob("*"))
        if p.is_file() and p.name != "summary.json"
    }


def _kitti(kit: Path, out: Path, *extra: str, seqs: str = "0001,0002,0003") -> int:
    argv = ["kitti", "--kitti-root", str(kit), "--seqs", seqs, "--out", str(out), *extra]
    return main(argv)


@pytest.fixture(scope="module")
def sequential(small_kit: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("sequential")
    assert _kitti(small_kit, out) == 0
    return out


def test_tracks_file_from_parts_is_byte_identical(tmp_path: Path) -> None:
    config = load_config("kitti")
    runs = {}
    for name, seed in (("b", 1), ("a", 2), ("c", 3)):  # not sorted: the order is kept
        dets, _ = synthetic_scene(num_objects=8, num_frames=30, seed=seed, scene=name)
        runs[name] = (dets, run_scene(dets, config).outputs)
    write_tracks_file(tmp_path / "whole.json", runs)
    parts = []
    for i, (name, (dets, outputs)) in enumerate(runs.items()):
        part = scenes.part_path(tmp_path, i, "json")
        part.parent.mkdir(exist_ok=True)
        part.write_bytes(tracks_scene_json(name, dets, outputs))
        parts.append((name, part))
    write_tracks_parts(tmp_path / "parts.json", parts)
    whole = (tmp_path / "whole.json").read_bytes()
    assert (tmp_path / "parts.json").read_bytes() == whole
    assert list(json.loads(whole)) == ["b", "a", "c"]


def test_nuscenes_submission_from_parts_is_byte_identical(tmp_path: Path) -> None:
    config = load_config("kitti")
    runs = {}
    for name, seed in (("scene-2", 4), ("scene-1", 5), ("scene-3", 6)):
        dets, _ = synthetic_scene(num_objects=8, num_frames=20, seed=seed, scene=name)
        dets = [replace(f, sample_token=f"{name}-{f.frame_id}") for f in dets]
        runs[name] = (dets, run_scene(dets, config).outputs)
    meta = {"use_camera": True}
    write_nuscenes_results(tmp_path / "whole.json", runs, meta=meta)
    parts = []
    for i, (name, run) in enumerate(runs.items()):
        part = tmp_path / f"{i}.json"
        part.write_text(json.dumps(nuscenes_results({name: run}), separators=(",", ":")))
        parts.append(part)
    write_nuscenes_parts(tmp_path / "parts.json", parts, meta=meta)
    assert (tmp_path / "parts.json").read_bytes() == (tmp_path / "whole.json").read_bytes()


def test_workers_give_the_sequential_files_and_metrics(
    small_kit: Path, sequential: Path, tmp_path: Path
) -> None:
    assert _kitti(small_kit, tmp_path, "--workers", "2") == 0
    assert _files(tmp_path) == _files(sequential)
    assert sorted(_files(tmp_path)) == [
        "data/0001.txt",
        "data/0002.txt",
        "data/0003.txt",
        "tracks.json",
    ]
    assert not (tmp_path / scenes.PARTS_DIR).exists()
    par = json.loads((tmp_path / "summary.json").read_text())
    seq = json.loads((sequential / "summary.json").read_text())
    assert par["metrics"] == seq["metrics"]  # the evaluation ran once, on the same files
    assert par["sequences"] == seq["sequences"] == ["0001", "0002", "0003"]
    assert (par["frames"], par["failed"]) == (447 + 60 + 120, {})
    assert par["parallel"]["backend"] == "processes"
    assert seq["parallel"]["backend"] == "sequential"


def test_a_scene_with_a_malformed_file_fails_alone(
    small_kit: Path, sequential: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    kit = tmp_path / "kit"
    shutil.copytree(small_kit, kit)
    bad = kit / "detections" / "pointrcnn" / "training" / "Car" / "0002.txt"
    bad.write_text(bad.read_text().replace(",", ";", 3))  # row 1 is no longer CSV
    out = tmp_path / "out"
    assert _kitti(kit, out, "--workers", "2") == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "scene 0002" in err[0] and str(bad) in err[0], err
    summary = json.loads((out / "summary.json").read_text())
    assert list(summary["failed"]) == ["0002"]
    # the run failed and nothing was scored, said plainly (was "skipped: sequences failed:
    # ['0002']", read as the sequence skipped); the speed is of the sequences tracked
    assert summary["evaluation"] == (
        "not scored: the run failed on 0002; metrics over 0001, 0003 alone would not be the "
        "run's (--seqs 0001,0003 scores those)"
    )
    lines = captured.out.strip().splitlines()
    assert lines[0].startswith("tracked 0001, 0003 only: frames 567 "), lines
    assert lines[1].startswith(
        "run failed on 1 of 3 sequences (0002: the error below); nothing was scored: "
    ), lines
    assert not any("HOTA" in line or "skipped" in line for line in lines), lines
    # the other sequences' outputs are complete and the same as in the good run
    good = _files(sequential)
    files = _files(out)
    assert sorted(files) == ["data/0001.txt", "data/0003.txt", "tracks.json"]
    assert files["data/0001.txt"] == good["data/0001.txt"]
    assert files["data/0003.txt"] == good["data/0003.txt"]
    assert list(json.loads(files["tracks.json"])) == ["0001", "0003"]


def test_a_run_whose_every_scene_failed_prints_no_speed(
    small_kit: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    kit = tmp_path / "kit"
    shutil.copytree(small_kit, kit)
    bad = kit / "detections" / "pointrcnn" / "training" / "Car" / "0002.txt"
    bad.write_text(bad.read_text().replace(",", ";", 3))
    assert _kitti(kit, tmp_path / "out", seqs="0002") == 2
    captured = capsys.readouterr()
    # (was "frames 0  tracker 0.00 s  - frames/s" and "skipped: sequences failed: ['0002']")
    assert captured.out.strip().splitlines() == [
        "run failed on every sequence (0002: the error below); nothing was scored"
    ]
    assert "scene 0002" in captured.err


@dataclass(frozen=True, slots=True)
class DiesOnce:
    """A job whose worker process dies (os._exit, like an OOM kill) the first time it runs
    scene ``victim``; the marker file remembers across processes that it already died."""

    inner: KittiSceneJob
    victim: str
    marker: Path

    def process(self, index: int, scene: str, data: Any) -> scenes.SceneRecord:
        if scene == self.victim and not self.marker.exists():
            self.marker.touch()
            os._exit(1)
        return self.inner.process(index, scene, data)


def _dies_once_job(kit: Path, out: Path, marker: Path) -> DiesOnce:
    config = load_config("kitti", overrides={"categories": ["car", "pedestrian", "cyclist"]})
    calibrate, profile, _ = score_source(config, "pointrcnn", None)
    inner = KittiSceneJob(
        kitti_root=kit,
        detector="pointrcnn",
        poses="orbslam3",
        classes=("car", "pedestrian", "cyclist"),
        config=config,
        out=out,
        label_dir=kit / "training" / "label_02",
        with_gt=False,
        keep=False,
        record=None,
        calibrate=calibrate,
        profile=profile,
    )
    return DiesOnce(inner, victim="0002", marker=marker)


def _assemble(records: list[scenes.SceneRecord], out: Path) -> None:
    assert [r.error for r in records] == [None, None, None]
    parts = [(r.scene, scenes.part_path(out, r.index, "json")) for r in records]
    write_tracks_parts(out / "tracks.json", parts)
    scenes.remove_parts(out)


def test_a_worker_that_dies_is_replaced_and_its_scene_run_again(
    small_kit: Path, sequential: Path, tmp_path: Path
) -> None:
    out, marker = tmp_path / "out", tmp_path / "died"
    job = _dies_once_job(small_kit, out, marker)
    records = scenes.run_scenes(
        job, ["0001", "0002", "0003"], parallel=scenes.Parallelism(workers=2), quiet=True
    )
    assert marker.exists()  # it did die once
    _assemble(records, out)
    assert _files(out) == _files(sequential)


def test_workers_on_a_basversion_file_and_an_unsafe_scene_name(tmp_path: Path) -> None:
    scenes_in = {}
    for name, seed in (("s2", 1), ("s1", 2), ("../escape", 3)):
        dets, _ = synthetic_scene(num_objects=8, num_frames=25, seed=seed, scene=name)
        scenes_in[name] = dets
    path = tmp_path / "in.json"
    write_baseversion(path, scenes_in)
    runs = {}
    for workers in ("1", "2"):
        out = tmp_path / f"w{workers}"
        argv = ["track", str(path), "--kitti-results", "--workers", workers, "--out", str(out)]
        assert main(argv) == 0  # "../escape" is escaped in its file name (issue #15)
        runs[workers] = _files(out)
    assert runs["1"] == runs["2"]
    assert sorted(runs["2"]) == [
        "data/%2E.%2Fescape.txt",
        "data/s1.txt",
        "data/s2.txt",
        "tracks.json",
    ]
    assert list(json.loads(runs["2"]["tracks.json"])) == ["s2", "s1", "../escape"]
    assert not (tmp_path / "escape.txt").exists()


def test_ray_without_the_extra_is_a_one_line_error(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    dets, _ = synthetic_scene(num_objects=3, num_frames=5, seed=0, scene="s")
    write_baseversion(tmp_path / "in.json", {"s": dets, "t": dets})
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as when not installed
    assert main(["track", str(tmp_path / "in.json"), "--ray", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install -e '.[ray]'" in err[0], err


def test_workers_must_be_positive(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["track", "x.json", "--workers", "0", "--out", "o"])
    assert exc.value.code == 2
    assert "--workers: must be at least 1" in capsys.readouterr().err


KITTI21 = ",".join(f"{i:04d}" for i in range(21))


@pytest.fixture(scope="module")
def kitti21_sequential(kitti_root: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The sequential run on the 21 training sequences (10 have no labels: no evaluation)."""
    out = tmp_path_factory.mktemp("kitti21")
    assert _kitti(kitti_root, out, "--no-eval", seqs=KITTI21) == 0
    return out


def test_all_21_kitti_sequences_with_2_workers(
    kitti_root: Path, kitti21_sequential: Path, tmp_path: Path
) -> None:
    assert _kitti(kitti_root, tmp_path, "--no-eval", "--workers", "2", seqs=KITTI21) == 0
    files = _files(tmp_path)
    assert files == _files(kitti21_sequential)
    assert len(files) == 22


# Loaded by every Python process of a run (PYTHONPATH): each KITTI sequence's result file is
# written SLOW_WRITE seconds late; its task says when it begins to wait (a file named by its pid
# in WRITING) and when it goes on to write (<pid>.writes).
SLOW_WRITE_HOOK = """
import os, time
if os.environ.get("SLOW_WRITE"):
    import tracker.io.writers as writers
    write = writers.write_kitti_sequence
    def slow(*args, **kwargs):
        said = os.path.join(os.environ["WRITING"], str(os.getpid()))
        open(said, "w").close()
        time.sleep(float(os.environ["SLOW_WRITE"]))
        open(said + ".writes", "w").close()
        return write(*args, **kwargs)
    writers.write_kitti_sequence = slow
"""


def test_ctrl_c_waits_for_the_stopped_workers_once_not_once_each(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Workers that do not end on SIGTERM: waited for STOP_SECONDS in all (then killed),
    not STOP_SECONDS one after another (N x 10 s)."""
    monkeypatch.setattr(scenes, "STOP_SECONDS", 0.2)

    class Stuck:  # (a worker that ignores SIGTERM until killed)
        def __init__(self) -> None:
            self.alive, self.waits = True, []

        def terminate(self) -> None:
            pass

        def kill(self) -> None:
            self.alive = False

        def is_alive(self) -> bool:
            return self.alive

        def join(self, timeout: float | None = None) -> None:
            self.waits.append(timeout)
            if self.alive and timeout:
                time.sleep(timeout)

    class Pool:
        def __init__(self) -> None:
            self._processes = {pid: Stuck() for pid in range(4)}

        def shutdown(self, wait: bool, cancel_futures: bool) -> None:
            pass

    pool = Pool()
    t0 = time.monotonic()
    scenes._stop_workers(pool)  # type: ignore[arg-type]
    assert time.monotonic() - t0 < 0.6  # (4 x 0.2 s before)
    waits = [w for p in pool._processes.values() for w in p.waits if w]
    assert sum(waits) <= 0.2 + 0.05 and not any(p.alive for p in pool._processes.values())


@pytest.mark.parametrize("ctrl_c", ["once to the process group", "twice to the command"])
def test_ctrl_c_stops_the_workers_before_the_outputs_are_removed(
    kitti_root: Path, tmp_path: Path, ctrl_c: str
) -> None:
    """Ctrl-C while both workers track: the command stops them at once, the sequence not begun
    cancelled, then removes the run's outputs. (It waited for the workers to finish their
    sequences, minutes on long ones; a second Ctrl-C during that wait removed the outputs while
    the workers still wrote theirs, and the command hung at its exit.) Nothing of the run is
    left, and no process of it."""
    import signal
    import subprocess
    import time

    hook, writing, out = tmp_path / "hook", tmp_path / "writing", tmp_path / "out"
    hook.mkdir()
    writing.mkdir()
    (hook / "sitecustomize.py").write_text(SLOW_WRITE_HOOK)
    slow = 4.0
    env = {**os.environ, "PYTHONPATH": f"{hook}{os.pathsep}{ROOT}", "SLOW_WRITE": str(slow),
           "WRITING": str(writing)}  # fmt: skip
    argv = ["kitti", "--kitti-root", str(kitti_root), "--seqs", "0012,0014,0016", "--no-eval",
            "--workers", "2", "--out", str(out)]  # fmt: skip
    proc = subprocess.Popen(
        [sys.executable, "-m", "app.cli", *argv],
        cwd=ROOT,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,  # its own process group, as a terminal's job
    )
    try:
        deadline = time.monotonic() + 300
        while len(list(writing.iterdir())) < 2:  # both workers in a sequence's task
            assert proc.poll() is None, proc.communicate()[0][-3000:]
            assert time.monotonic() < deadline, "timed out waiting for the workers"
            time.sleep(0.05)
        if ctrl_c == "once to the process group":  # (what a terminal's Ctrl-C sends)
            os.killpg(proc.pid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGINT)
            time.sleep(0.2)
            proc.send_signal(signal.SIGINT)
        output, _ = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.communicate()
    # (a second Ctrl-C after the clean-up, as the interpreter exits, ends it by that signal)
    assert proc.returncode in (130, -signal.SIGINT), output[-3000:]
    assert "mctrack kitti: interrupted" in output and "Traceback" not in output, output[-3000:]
    assert not out.exists()  # (it made --out: gone, empty)
    # stopped in their sequences (they went on to write them, and the third began)
    assert len(list(writing.iterdir())) == 2 and not list(writing.glob("*.writes"))
    time.sleep(slow + 1)  # past the moment a worker left running would write its sequence
    assert not out.exists()
    with pytest.raises(ProcessLookupError):  # (its workers, fork server and resource tracker)
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            os.killpg(proc.pid, 0)
            time.sleep(0.1)


def test_unlabelled_sequences_are_named_and_left_out_of_the_score(
    kitti_root: Path, tmp_path: Path, caplog: pytest.LogCaptureFixture, capsys: Any
) -> None:
    """A run over labelled and unlabelled sequences scores the labelled ones (as a run of those
    alone does), says which were left out, and compares as such; a --labels folder that is not
    there is an error."""
    kit = tmp_path / "kit"  # the kit with the labels of 0006 only
    (kit / "training" / "label_02").mkdir(parents=True)
    for sub in ("calib", "pose_orbslam3"):
        (kit / "training" / sub).symlink_to(kitti_root / "training" / sub)
    label = kitti_root / "training" / "label_02" / "0006.txt"  # a linked file is read as any
    (kit / "training" / "label_02" / "0006.txt").symlink_to(label)
    (kit / "detections").symlink_to(kitti_root / "detections")
    common = {"kitti_root": kit, "classes": ["car"], "detector": "virconv", "quiet": True}
    with caplog.at_level("WARNING"):
        both = run_kitti(**common, seqs=["0006", "0010"], out=tmp_path / "both")
    alone = run_kitti(**common, seqs=["0006"], out=tmp_path / "alone")
    assert both["metrics"] == alone["metrics"] and both["evaluated_sequences"] == ["0006"]
    assert "no labels for ['0010']" in both["evaluation"] and "['0010']" in caplog.text
    assert alone["evaluated_sequences"] == ["0006"] and "evaluation" not in alone
    compare = ["compare", str(tmp_path / "alone"), str(tmp_path / "both")]
    assert main([*compare, "--out", str(tmp_path / "cmp")]) == 0
    assert main(["report", str(tmp_path / "both"), "--out", str(tmp_path / "rep")]) == 0
    page = (tmp_path / "rep" / "index.html").read_text()
    assert "A: scored on [&#x27;0006&#x27;]; no labels for [&#x27;0010&#x27;]" in page
    assert "2 sequence(s) (1 scored)" in page

    argv = ["kitti", "--kitti-root", str(kit), "--seqs", "0006", "--classes", "car"]
    code = main([*argv, "--labels", str(tmp_path / "nope"), "--out", str(tmp_path / "x")])
    err = capsys.readouterr().err
    assert code == 2 and f"{tmp_path / 'nope'}: --labels folder not found" in err


# ---- Ray (optional extra) ------------------------------------------------------------------


@pytest.fixture(scope="module")
def local_ray(small_kit: Path) -> Any:
    """A local Ray instance on loopback with 2 CPUs, started once for the Ray tests."""
    ray = pytest.importorskip("ray", reason="Ray is an optional extra: pip install -e '.[ray]'")
    # workers must import this test module (DiesOnce) by name, like the driver does
    old = os.environ.get("PYTHONPATH")
    os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT), old) if p)
    ray.init(
        address="local",
        num_cpus=2,
        include_dashboard=False,
        _node_ip_address="127.0.0.1",
        log_to_driver=False,
    )
    yield ray
    ray.shutdown()
    if old is None:
        os.environ.pop("PYTHONPATH", None)
    else:
        os.environ["PYTHONPATH"] = old


def test_ray_gives_the_sequential_files(
    local_ray: Any, small_kit: Path, sequential: Path, tmp_path: Path
) -> None:
    summary = run_kitti(
        kitti_root=small_kit,
        seqs=["0001", "0002", "0003"],
        classes=["car", "pedestrian", "cyclist"],
        out=tmp_path,
        quiet=True,
        parallel=scenes.Parallelism(ray="auto"),  # joins the instance the fixture started
    )
    assert _files(tmp_path) == _files(sequential)
    seq = json.loads((sequential / "summary.json").read_text())
    assert summary["metrics"] == seq["metrics"]
    assert summary["parallel"]["backend"] == "ray"
    assert local_ray.is_initialized()  # not shut down: the run did not start it


def test_ray_retries_a_task_whose_worker_died(
    local_ray: Any, small_kit: Path, sequential: Path, tmp_path: Path
) -> None:
    out, marker = tmp_path / "out", tmp_path / "died"
    job = _dies_once_job(small_kit, out, marker)
    records = scenes.run_scenes(
        job, ["0001", "0002", "0003"], parallel=scenes.Parallelism(ray="auto"), quiet=True
    )
    assert marker.exists()
    _assemble(records, out)
    assert _files(out) == _files(sequential)


def test_ray_on_all_21_kitti_sequences(
    local_ray: Any, kitti_root: Path, kitti21_sequential: Path, tmp_path: Path
) -> None:
    run_kitti(
        kitti_root=kitti_root,
        seqs=KITTI21.split(","),
        classes=["car", "pedestrian", "cyclist"],
        evaluate=False,
        quiet=True,
        out=tmp_path,
        parallel=scenes.Parallelism(ray="auto"),
    )
    assert _files(tmp_path) == _files(kitti21_sequential)


@dataclass(frozen=True, slots=True)
class SlowWriter:
    """A job whose scene writes as it tracks (a line every 10 ms, after its worker's pid) for
    ``seconds``, then its file: what a scene of a stopped run would write after the clean-up."""

    folder: Path
    seconds: float

    def process(self, index: int, scene: str, data: Any) -> scenes.SceneRecord:
        import time

        writes = self.folder / f"{scene}.writes"
        writes.write_text(f"{os.getpid()}\n")
        end = time.monotonic() + self.seconds
        while time.monotonic() < end:
            with writes.open("a") as fh:
                fh.write("tracking\n")
            time.sleep(0.01)
        (self.folder / f"{scene}.txt").write_text("written after the stop")
        return scenes.SceneRecord(index, scene)


def test_ctrl_c_under_ray_stops_the_tasks_before_the_clean_up(
    local_ray: Any, tmp_path: Path
) -> None:
    """Ctrl-C while two Ray tasks track (a third waiting for a CPU), on a joined instance (one
    that outlives the command, as a cluster): the run cancels the tasks, kills the running
    ones' workers and waits until they have ended, before the caller's clean-up. It only shut
    Ray down, which leaves a joined cluster's tasks running: they wrote on after the clean-up,
    and the waiting one began."""
    import signal
    import threading
    import time

    job = SlowWriter(tmp_path, seconds=4.0)
    items = [(i, s, None) for i, s in enumerate(["s0", "s1", "s2"])]
    began: list[Path] = []

    def ctrl_c() -> None:  # (SIGINT to this process, as a terminal's Ctrl-C)
        deadline = time.monotonic() + 60
        while len(began) < 2 and time.monotonic() < deadline:
            began[:] = sorted(tmp_path.glob("*.writes"))
            time.sleep(0.02)
        os.kill(os.getpid(), signal.SIGINT)

    records: list[scenes.SceneRecord] = []
    sender = threading.Thread(target=ctrl_c)
    start = time.monotonic()
    sender.start()
    with pytest.raises(KeyboardInterrupt):
        scenes._run_ray(job, items, scenes.Parallelism(ray="auto"), records.append)
    stopped = time.monotonic()
    left = {p.name: p.read_bytes() for p in tmp_path.iterdir()}  # (where the clean-up begins)
    sender.join()
    assert [p.name for p in began] == ["s0.writes", "s1.writes"] and not records
    assert stopped - start < job.seconds  # (stopped in their scenes, not at their end)
    time.sleep(job.seconds + 1)  # past the moment a task left running would write its file
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == left  # not a line since
    pids = [int(p.read_text().split()[0]) for p in began]
    deadline = time.monotonic() + 10
    while [pid for pid in pids if _alive(pid)] and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [pid for pid in pids if _alive(pid)]  # (force: their workers killed)
    assert local_ray.is_initialized()  # (the instance it joined runs on)


def _alive(pid: int) -> bool:
    """A process that runs (a zombie, exited and not yet reaped, does not)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat.rsplit(")", 1)[-1].split()[0] != "Z"


def test_waymo_segments_with_workers_and_a_segment_that_fails_alone(tmp_path: Path) -> None:
    from tests.test_waymo import SEGMENT, write_segment

    root = write_segment(tmp_path / "waymo")
    for copy in ("seg-b", "seg-a", "seg-broken"):
        for sub, ext in (("ts_info", "json"), ("ego_info", "npz"), ("dets", "npz")):
            shutil.copy(root / sub / f"{SEGMENT}.{ext}", root / sub / f"{copy}.{ext}")
    (root / "ts_info" / "seg-broken.json").write_text("[1, 2")  # truncated JSON
    runs = {}
    for workers in ("1", "2"):
        out = tmp_path / f"w{workers}"
        argv = ["waymo", "--data-root", str(root), "--detections", str(root / "dets")]
        assert main([*argv, "--workers", workers, "--out", str(out)]) == 2
        runs[workers] = _files(out)
        summary = json.loads((out / "summary.json").read_text())
        assert list(summary["failed"]) == ["seg-broken"]
        assert summary["segments"] == ["seg-a", "seg-b", SEGMENT]
    assert runs["1"] == runs["2"]
    assert "results/vehicle/seg-a.npz" in runs["2"]
    assert not any("seg-broken" in name for name in runs["2"])


@pytest.mark.parametrize("tracked", [1, 0])
def test_nuscenes_and_waymo_say_a_failed_run_as_kitti_does(
    tracked: int, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run with a failed scene says so in one line, and one whose every scene failed prints
    no speed (both printed "0 frames, - frames/s" and nuScenes "skipped: scenes failed: [...]",
    read as the scenes skipped)."""
    import argparse

    import app.nuscenes
    import app.waymo

    names = ["scene-a", "scene-b"][: tracked + 1]
    failed = {"scene-b" if tracked else "scene-a": "boom"}
    common = {"frames": 40 * tracked, "tracker_seconds": 0.1 * tracked, "boxes_written": 7}
    common |= {
        "tracker_fps": 400.0 if tracked else None,
        "results": "OUT/results",
        "failed": failed,
    }
    app.nuscenes._print_summary(
        {**common, "scenes": names, "evaluation": "not scored: the run failed on scene-b"}
    )
    tracked_names = [n for n in names if n not in failed]  # (a waymo summary's "segments")
    monkeypatch.setattr(app.waymo, "run_waymo", lambda **_: {**common, "segments": tracked_names})
    monkeypatch.setattr(app.waymo, "check_output_folder", lambda out: None)
    args = argparse.Namespace(
        out="OUT", data_root=".", detections=".", gt=None, segments=None, config="waymo",
        mode=None, motion=False, record=False, workers=1, ray=None,
    )  # fmt: skip
    assert app.waymo.run(args) == 2
    out = capsys.readouterr().out.splitlines()
    if tracked:
        assert out == [
            "tracked 1 of 2 scenes, 40 frames, tracker 0.10 s (400.0 frames/s), 7 boxes -> "
            "OUT/results",
            "run failed on 1 of 2 scenes (scene-b: the error below); nothing was scored",
            "tracked 1 of 2 segments, 40 frames, 400.0 frames/s -> OUT/results 7",
            "run failed on 1 of 2 segments (scene-b: the error below); results written for "
            "the others alone",
        ]
    else:
        assert out == [
            "run failed on every scene (scene-a: the error below); nothing was scored",
            "run failed on every segment (scene-a: the error below); no results",
        ]
