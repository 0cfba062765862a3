"""`mctrack tune --ray`: the same trials as the local search; resume after Ctrl-C or a kill,
without redoing finished trials; a killed trial process run again; the one-line errors.

The runs are tiny (car, PointRCNN, the two shortest labelled sequences, 2 folds) and each runs
in its own process, as a user would: the Ray runs start a local instance on 127.0.0.1 with 2
CPUs (``--ray --workers 2``), and a test can interrupt or kill them."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from app.cli import main

ROOT = Path(__file__).resolve().parents[1]
SEQS = "0012,0014"  # 78 + 106 frames: a trial takes 0.1 to 1 s
TRIALS = 6  # 4 random start-up trials (app.tune.startup_trials), then 2 proposed by TPE


def _tune_args(kitti_root: Path, out: Path, trials: int, *extra: str) -> list[str]:
    return ["tune", "--kitti-root", str(kitti_root), "--class", "car", "--detectors",
            "pointrcnn", "--seqs", SEQS, "--folds", "2", "--trials", str(trials),
            "--workers", "2", "--out", str(out), *extra]  # fmt: skip


def _start(args: list[str], temp: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    """The command in its own process; its temp folder ($TMPDIR: the work folders of the tune
    and its trials) is ``temp``, so what a killed run leaves stays in the test's folder. Ray's
    own files stay where they were (a session's socket paths must be short)."""
    ray_tmp = os.environ.get("RAY_TMPDIR") or os.environ.get("TMPDIR") or "/tmp"
    temp.mkdir(exist_ok=True)
    return subprocess.Popen(
        [sys.executable, "-m", "app.cli", *args],
        cwd=ROOT,
        env={**os.environ, "TMPDIR": str(temp), "RAY_TMPDIR": ray_tmp, **(env or {})},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,  # its own process group, so a test can kill the whole run
    )


def _finish(proc: subprocess.Popen, timeout: float = 600) -> tuple[int, str]:
    try:
        output, _ = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        raise
    return proc.returncode, output


def _run(args: list[str], temp: Path) -> tuple[int, str]:
    return _finish(_start(args, temp))


def _left(temp: Path) -> list[str]:
    """What the runs left in their temp folder: nothing, once a run after the kills ended (it
    removed the work folders of the killed processes, and its own)."""
    return sorted(p.name for p in temp.iterdir())


def _finished(out: Path, search: str) -> dict[str, str]:
    """Each finished trial's result file (Ray Tune's record of it: pid, time, objective)."""
    found = {}
    for path in sorted((out / "ray_tune" / search).glob("trial_*/result.json")):
        text = path.read_text()
        if text.strip():
            found[path.parent.name] = text
    return found


def _saved_trials(out: Path, search: str) -> list[dict[str, Any]]:
    """The trials as of Ray Tune's last save: what a resume keeps. Read from the snapshot of
    that save (app.tune_ray._Snapshot), as the copy of the state in the experiment folder may
    be cut short by a kill, and a trial's result file is written before the save."""
    snapshot = out / "ray_tune" / f"{search}.resume.zip"
    if not snapshot.is_file():
        return []
    with zipfile.ZipFile(snapshot) as archive:
        names = sorted(n for n in archive.namelist() if n.startswith("experiment_state-"))
        state = json.loads(archive.read(names[-1]))
    return [json.loads(t[0]) for t in state["trial_data"]]


def _saved(out: Path, search: str) -> set[str]:
    """The trials finished as of the last save."""
    return {
        f"trial_{t['trial_id']}" for t in _saved_trials(out, search) if t["status"] == "TERMINATED"
    }


def _wait_until(proc: subprocess.Popen, ready: Callable[[], bool], timeout: float = 300) -> None:
    start = time.monotonic()
    while not ready():
        if proc.poll() is not None:
            pytest.fail(f"the run ended first:\n{proc.communicate()[0][-3000:]}")
        if time.monotonic() - start > timeout:
            os.killpg(proc.pid, signal.SIGKILL)
            pytest.fail("timed out waiting for the run")
        time.sleep(0.1)


def _searches(record: dict[str, Any]) -> list[list[dict[str, Any]]]:
    """The trials (settings and objective) of every search, in order: folds, then final."""
    return [fold["trials"] for fold in record["cv"]] + [record["final"]["trials"]]


def _prefix(record: dict[str, Any], n: int) -> list[list[dict[str, Any]]]:
    return [trials[:n] for trials in _searches(record)]


def _descendants(pid: int) -> list[tuple[int, str]]:
    """(pid, command line) of every process below ``pid``."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path(f"/proc/{entry}/stat").read_text()
            except OSError:
                continue
            children.setdefault(int(stat.rsplit(")", 1)[1].split()[1]), []).append(int(entry))
    found, todo = [], list(children.get(pid, []))
    while todo:
        child = todo.pop()
        try:
            cmdline = Path(f"/proc/{child}/cmdline").read_text().replace("\0", " ")
        except OSError:
            continue
        found.append((child, cmdline))
        todo += children.get(child, [])
    return found


def _trial_processes(proc: subprocess.Popen) -> list[int]:
    """The run's Ray Tune trial processes (a process between two searches has another name)."""
    return [pid for pid, cmd in _descendants(proc.pid) if cmd.startswith("ray::ImplicitFunc")]


# Loaded by every Python process of a run (PYTHONPATH), so a test can kill a trial process at a
# chosen moment. SLOW_FIRST_RESET=MARKER: the first reset of a reused trial process (Ray Tune
# handing it its next trial) creates MARKER, then sleeps. SLOW_REPORT=SECONDS: each trial sleeps
# that long before it reports its result (it is running meanwhile).
HOOKS = """
import os, time
if os.environ.get("SLOW_FIRST_RESET"):
    from ray.tune.trainable import function_trainable as ft
    reset = ft.FunctionTrainable.reset_config
    def slow(self, new_config):
        try:
            os.close(os.open(os.environ["SLOW_FIRST_RESET"], os.O_CREAT | os.O_EXCL))
            time.sleep(3)
        except FileExistsError:
            pass
        return reset(self, new_config)
    ft.FunctionTrainable.reset_config = slow
if os.environ.get("SLOW_REPORT"):
    import ray.tune
    report = ray.tune.report
    def slow_report(*args, **kwargs):
        time.sleep(float(os.environ["SLOW_REPORT"]))
        return report(*args, **kwargs)
    ray.tune.report = slow_report
"""


def _hook_env(folder: Path, **env: str) -> dict[str, str]:
    """The environment of a run with :data:`HOOKS` (``env`` chooses which)."""
    folder.mkdir(exist_ok=True)
    (folder / "sitecustomize.py").write_text(HOOKS)
    return {"PYTHONPATH": f"{folder}{os.pathsep}{ROOT}", **env}


@pytest.fixture(scope="module")
def ray_installed() -> None:
    pytest.importorskip("ray.tune", reason="Ray Tune is an optional extra: pip install -e '.[ray]'")


@pytest.fixture(scope="module")
def local_record(kitti_root: Path, ray_installed: None, tmp_path_factory: Any) -> dict[str, Any]:
    """The local search (Optuna in this process, a process pool), the reference."""
    out = tmp_path_factory.mktemp("tune-local")
    temp = tmp_path_factory.mktemp("tune-local-temp")
    status, output = _run(_tune_args(kitti_root, out, TRIALS), temp)
    assert status == 0, output[-3000:]
    assert _left(temp) == []
    return json.loads((out / "tune.json").read_text())


def test_ray_proposes_the_local_trials_and_finds_the_same_best(
    kitti_root: Path, local_record: dict[str, Any], tmp_path: Path
) -> None:
    temp = tmp_path / "temp"
    status, output = _run(
        _tune_args(kitti_root, tmp_path, TRIALS, "--ray", "--max-concurrent", "1"), temp
    )
    assert status == 0, output[-3000:]
    assert _left(temp) == []
    record = json.loads((tmp_path / "tune.json").read_text())
    assert record["ray"]["max_concurrent"] == 1 and record["ray"]["cluster_cpus"] == 2
    # trial for trial: the same settings proposed and the same objective, in every search
    assert _searches(record) == _searches(local_record)
    assert all(len(trials) == TRIALS for trials in _searches(record))
    assert len({json.dumps(t["params"], sort_keys=True) for t in _searches(record)[0]}) == TRIALS
    assert [f["best"] for f in record["cv"]] == [f["best"] for f in local_record["cv"]]
    assert record["final"]["best"] == local_record["final"]["best"]
    assert record["cross_validated"] == local_record["cross_validated"]
    assert record["final"]["in_sample"] == local_record["final"]["in_sample"]


def test_ray_resumes_after_ctrl_c_and_a_kill_and_retries_a_killed_trial(
    kitti_root: Path, local_record: dict[str, Any], tmp_path: Path
) -> None:
    trials = 4
    args = _tune_args(kitti_root, tmp_path, trials, "--ray", "--max-concurrent", "1")
    temp = tmp_path / "temp"

    # Each trial waits 1 s before it reports, so the Ctrl-C and the kill land inside a search,
    # not after its last trial: unslowed, a trial can take 0.1 s (seen in CI).
    slow = _hook_env(tmp_path / "hook", SLOW_REPORT="1")

    # 1. Ctrl-C once a trial of the first search is done: Ray Tune saves, the run stops
    proc = _start(args, temp, slow)
    _wait_until(proc, lambda: len(_finished(tmp_path, "fold0")) >= 1)
    proc.send_signal(signal.SIGINT)
    status, output = _finish(proc)
    assert status == 130, output[-3000:]
    assert "run the same command again to resume" in output
    assert not (tmp_path / "tune.json").exists()
    before_ctrl_c = _finished(tmp_path, "fold0")
    assert len(before_ctrl_c) >= 1
    # Ctrl-C: saved one last time. A trial whose result lands in the very moment of the signal
    # can miss that state (seen under load); a resume runs it again, so only the saved ones
    # must survive untouched.
    saved_at_ctrl_c = _saved(tmp_path, "fold0")
    assert saved_at_ctrl_c and saved_at_ctrl_c <= set(before_ctrl_c)
    before_ctrl_c = {k: v for k, v in before_ctrl_c.items() if k in saved_at_ctrl_c}

    # 2. resumed, then killed outright (the whole process group) during the second search
    proc = _start(args, temp, slow)
    # (a trial both saved and with its result file copied to the experiment folder: Ray Tune
    # copies that file in the background, and under load it can land after the save)
    _wait_until(proc, lambda: bool(_saved(tmp_path, "fold1") & set(_finished(tmp_path, "fold1"))))
    os.killpg(proc.pid, signal.SIGKILL)
    _finish(proc)
    # Ray Tune copies its state to the experiment folder in the background, file by file: a
    # kill during the copy leaves files of two saves, or half a file. Make it so, every time.
    for path in (tmp_path / "ray_tune" / "fold1").glob("*-*.*"):
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    assert not (tmp_path / "tune.json").exists()
    fold0 = _finished(tmp_path, "fold0")
    assert len(fold0) == trials
    assert {k: fold0[k] for k in before_ctrl_c} == before_ctrl_c  # not run again
    before_kill = {k: v for k, v in _finished(tmp_path, "fold1").items()
                   if k in _saved(tmp_path, "fold1")}  # fmt: skip
    assert before_kill
    assert len(before_ctrl_c) < trials or len(before_kill) < trials

    # 3. resumed to the end, with the trial process killed once during the last search: Ray
    # Tune runs that trial again (FailureConfig). Each trial waits 2 s before it reports, so the
    # kill lands in a trial, not after the search's last one (seen under load).
    killed = _left(temp)  # the work folders of the killed tune and trial
    assert killed and all(name.startswith("mctrack-") for name in killed), killed
    proc = _start(args, temp, _hook_env(tmp_path / "hook", SLOW_REPORT="2"))
    _wait_until(proc, lambda: len(_finished(tmp_path, "all")) >= 1 and _trial_processes(proc))
    for pid in _trial_processes(proc):  # this run's trial process (reused from trial to trial)
        os.kill(pid, signal.SIGKILL)
    status, output = _finish(proc)
    assert status == 0, output[-3000:]
    record = json.loads((tmp_path / "tune.json").read_text())
    assert record["ray"]["resumed_searches"] == ["fold0", "fold1"]
    assert list((tmp_path / "ray_tune" / "all").glob("trial_*/error.txt"))  # the killed trial
    slowed = [json.loads(text)["time_this_iter_s"] for text in _finished(tmp_path, "all").values()]
    assert min(slowed) >= 2  # (the hook took effect)
    assert _finished(tmp_path, "fold0") == fold0
    fold1 = _finished(tmp_path, "fold1")
    assert {k: fold1[k] for k in before_kill} == before_kill
    for search in ("fold0", "fold1", "all"):  # every trial ran once: no repeats, none missing
        assert len(list((tmp_path / "ray_tune" / search).glob("trial_*"))) == trials
    # and the interruptions changed nothing: the trials of an uninterrupted search (the first 4
    # of the reference's 6: both have 4 random start-up trials, and a proposal depends only on
    # the trials before it)
    assert _searches(record) == _prefix(local_record, trials)
    assert _left(temp) == []  # the killed runs' work folders too

    # 4. the same --out with another command line is refused, naming what changed
    status, output = _run(_tune_args(kitti_root, tmp_path, trials + 1, "--ray"), temp)
    assert status == 2, output[-3000:]
    lines = [line for line in output.splitlines() if "error" in line]
    assert len(lines) == 1 and "trials 4 -> 5" in lines[0] and "another --out" in lines[0]


def test_ray_runs_again_a_trial_whose_process_died_before_it_began(
    kitti_root: Path, local_record: dict[str, Any], tmp_path: Path
) -> None:
    """Ray Tune fails (not retries) a trial whose reused process dies while being handed it.
    A resume runs such a trial again, and so does the command itself; the search is the
    uninterrupted one."""
    marker, out, temp = tmp_path / "resetting", tmp_path / "out", tmp_path / "temp"
    # (each trial waits 1 s before it reports, so the kills land in the first search)
    env = _hook_env(tmp_path / "hook", SLOW_FIRST_RESET=str(marker), SLOW_REPORT="1")
    args = _tune_args(kitti_root, out, 4, "--ray", "--max-concurrent", "1")

    def kill_the_resetting_process(proc: subprocess.Popen) -> None:
        _wait_until(proc, marker.exists)
        workers = _trial_processes(proc)
        assert workers, _descendants(proc.pid)
        for pid in workers:
            os.kill(pid, signal.SIGKILL)

    # 1. the failed trial saved, then the run killed: the resume runs it again
    proc = _start(args, temp, env)
    kill_the_resetting_process(proc)
    _wait_until(proc, lambda: any(t["status"] == "ERROR" for t in _saved_trials(out, "fold0")))
    os.killpg(proc.pid, signal.SIGKILL)
    _finish(proc)
    # 2. resumed, and the process killed again while being handed a trial: the command runs
    # that trial again once the others are done
    marker.unlink()
    proc = _start(args, temp, env)
    kill_the_resetting_process(proc)
    status, output = _finish(proc)
    assert status == 0, output[-3000:]
    assert "failed as their worker process died; running them again" in output
    assert len(list((out / "ray_tune" / "fold0").glob("trial_*/error.txt"))) == 2
    for search in ("fold0", "fold1", "all"):
        assert len(list((out / "ray_tune" / search).glob("trial_*"))) == 4
    record = json.loads((out / "tune.json").read_text())
    assert _searches(record) == _prefix(local_record, 4)
    assert _left(temp) == []  # the killed run's work folder too


def test_ray_without_the_extra_is_a_one_line_error(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` fails as when not installed
    assert main(["tune", "--ray", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install -e '.[ray]'" in err[0], err
    assert not any(tmp_path.iterdir())


def test_max_concurrent_needs_ray(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["tune", "--max-concurrent", "2", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--max-concurrent needs --ray" in err[0], err


def test_seqs_must_be_labelled_and_at_least_one_per_fold(
    kitti_root: Path, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    root = str(kitti_root)
    args = ["tune", "--kitti-root", root, "--folds", "2", "--out", str(tmp_path)]
    assert main([*args, "--seqs", "0000,0001"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--seqs: no labels for 0000" in err[0], err
    assert main(["tune", "--seqs", "0001", "--folds", "2", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--folds 2 needs at least as many --seqs (got 1)" in err[0], err


def test_a_resume_puts_back_the_last_whole_save(tmp_path: Path) -> None:
    """What a kill during Ray Tune's background copy leaves (half a state file, a newer
    session's file, a trial the saved state never held) is replaced by the snapshot."""
    tune_ray = pytest.importorskip("app.tune_ray")
    staging, experiment = tmp_path / "staging", tmp_path / "fold1"
    staging.mkdir()
    experiment.mkdir()
    trial = json.dumps({"trial_id": "aaa", "status": "TERMINATED"})
    saved = {
        "experiment_state-s1.json": json.dumps({"trial_data": [[trial, "{}"]]}).encode(),
        "search_gen_state-s1.json": b"generator",
        "searcher-state-s1.pkl": b"searcher",
    }
    for name, data in saved.items():
        (staging / name).write_bytes(data)
    (staging / "trial_aaa").mkdir()  # trial folders are not part of the snapshot
    snapshot = tmp_path / "fold1.resume.zip"
    tune_ray.write_snapshot(staging, snapshot)

    for name, data in saved.items():
        (experiment / name).write_bytes(data[: len(data) // 2])
    (experiment / "experiment_state-s2.json").write_text("{")
    (experiment / "tuner.pkl").write_bytes(b"tuner")
    for name in ("trial_aaa", "trial_bbb"):
        (experiment / name).mkdir()
        (experiment / name / "result.json").write_text("{}")
    assert tune_ray.prepare_resume(experiment) == "restored"
    assert {p.name: p.read_bytes() for p in experiment.glob("*-*.*")} == saved
    assert sorted(p.name for p in experiment.iterdir()) == [
        *sorted(saved),
        "trial_aaa",
        "tuner.pkl",
    ]

    other = tmp_path / "fold2"  # stopped before a save after a trial started: no snapshot
    (other / "trial_ccc").mkdir(parents=True)
    (other / "experiment_state-s1.json").write_text('{"trial_data": []}')
    (other / "tuner.pkl").write_bytes(b"tuner")
    assert tune_ray.prepare_resume(other) == "started over" and not other.exists()
    assert tune_ray.prepare_resume(other) == "new"
    # a folder an earlier version wrote (trials saved, no snapshot): left to Ray Tune's restore
    (other / "trial_ccc").mkdir(parents=True)
    (other / "experiment_state-s1.json").write_text(json.dumps({"trial_data": [[trial, "{}"]]}))
    (other / "tuner.pkl").write_bytes(b"tuner")
    assert tune_ray.prepare_resume(other) == "unsnapshotted" and (other / "trial_ccc").is_dir()

    # a snapshot whose compressed data is damaged (zlib fails): a one-line error
    with zipfile.ZipFile(snapshot) as archive:
        info = archive.getinfo("experiment_state-s1.json")
    whole = bytearray(snapshot.read_bytes())
    data = info.header_offset + 30 + len(info.filename) + len(info.extra)
    whole[data : data + 4] = b"\xff\xff\xff\xff"  # not a deflate block
    snapshot.write_bytes(bytes(whole))
    with pytest.raises(tune_ray.InputError, match="not a saved Ray Tune search"):
        tune_ray.restore_snapshot(experiment, snapshot)

    snapshot.write_bytes(b"PK not a zip")
    with pytest.raises(
        tune_ray.InputError, match=r"fold1\.resume\.zip: not a saved Ray Tune search"
    ):
        tune_ray.restore_snapshot(experiment, snapshot)


def test_a_resume_with_other_search_settings_is_refused(tmp_path: Path) -> None:
    """--search is recorded only when given: older folders resume, a dropped or changed --search
    is a change, its order and spelling are not."""
    tune_ray = pytest.importorskip("app.tune_ray")
    run_json = tmp_path / "ray_tune" / "run.json"
    run_json.parent.mkdir()
    run_json.write_text(json.dumps({"class": "car", "search": ["bev.buffer=float:0.1:0.6"]}))
    tune_ray.check_options(run_json, {"class": "car", "search": ["bev.buffer=float:0.1:0.6"]})
    for options in ({"class": "car"}, {"class": "car", "search": ["bev.buffer=float:0.2:0.6"]}):
        with pytest.raises(tune_ray.InputError, match=r"started with other options.*search"):
            tune_ray.check_options(run_json, options)
    run_json.write_text(json.dumps({"class": "car"}))  # a run from before --search
    tune_ray.check_options(run_json, {"class": "car"})
    with pytest.raises(tune_ray.InputError, match="search None -> "):
        tune_ray.check_options(run_json, {"class": "car", "search": ["bev.buffer=float:0.1:0.6"]})


def test_a_detector_without_a_shipped_profile_is_recorded_in_run_json() -> None:
    """A search of such a detector begun before its in-sample profile was fitted is not resumed
    after; the shipped detectors' run.json stays as it was (their folders still resume)."""
    tune_ray = pytest.importorskip("app.tune_ray")
    assert tune_ray.fitted_profile_option("pointrcnn,virconv, second_iou") == {}
    assert tune_ray.fitted_profile_option("pointrcnn,mydet") == {
        "in_sample_profile_fitted": ["mydet"]
    }
