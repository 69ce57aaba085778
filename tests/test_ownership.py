"""The ownership-and-commit contract of every command that writes (issue 57): nothing a user wrote
is overwritten (``export`` and ``plot`` included), a result is committed inside a target that
cannot be renamed (a mount point, a symbolic link), what cannot be written is refused before the
work, and damaged or half-started sweeps say what to do.

Mount points are tmpfs mounts in the test's folder (root only; skipped with the reason
elsewhere), always unmounted. Runs are the paper scenario for a few steps, in this process.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import hinfnn as H
from hinfnn import cli
from hinfnn.io import MARKER, foreign_files, load_metrics, read_marker, reserve_output

SRC = Path(H.__file__).resolve().parents[1]
TINY = ["--set", "simulation.t_final=0.02", "--set", "controller.kind=hinf", "--quiet", "--no-figures"]
SPEC = """
name = "tiny"
scenario = "paper"
controllers = ["hinf"]
samples = 2
seed = 3
[set]
"simulation.t_final" = 0.05
[vary]
"plant.arm.m1" = { distribution = "relative", percent = 10 }
"""


def _cli(args, capsys) -> tuple[int, str]:
    capsys.readouterr()
    code = cli.main([str(a) for a in args])
    return code, capsys.readouterr().err


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err, err
    return lines[0]


@contextlib.contextmanager
def tmpfs(path: Path, *, read_only: bool = False):
    """A tmpfs mounted at ``path`` (made here), unmounted at the end whatever happens."""
    if os.geteuid() != 0:
        pytest.skip("mounting a tmpfs needs root")
    path.mkdir(exist_ok=True)
    p = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro" if read_only else "rw", "none", str(path)],
                       capture_output=True, text=True)
    if p.returncode != 0:
        pytest.skip(f"mount -t tmpfs failed here: {p.stderr.strip()}")
    try:
        yield path
    finally:
        subprocess.run(["umount", "-l", str(path)], capture_output=True)


@pytest.fixture(scope="module")
def result(tmp_path_factory):
    """A tiny run written by ``hinfnn run`` (in this process)."""
    out = tmp_path_factory.mktemp("own") / "r"
    assert cli.main(["run", "paper", *TINY, "--out", str(out)]) == 0
    return out


def _copy(result, where: Path) -> Path:
    import shutil

    shutil.copytree(result, where)
    return where


# --- export and plot never overwrite the user's files -------------------------------------------------------


def test_export_refuses_every_file_hinfnn_did_not_write(tmp_path, result, capsys, monkeypatch):
    r = _copy(result, tmp_path / "r")
    monkeypatch.chdir(tmp_path)
    Path("notes.csv").write_text("mine")
    Path("spec.toml").write_text("name = 'my sweep'\n")
    Path("own").mkdir()
    Path("own/trajectory.csv").write_text("mine too")
    (r / "trajectory.csv").write_text("the user's, not in the marker")
    cases = [(["--csv", "--out", "notes.csv"], "notes.csv", "--out"),
             (["--parquet", "--out", "notes.csv"], "notes.csv", "--out"),
             (["--csv", "--out", "own"], "own/trajectory.csv", "--out"),
             (["--csv"], "r/trajectory.csv", "export"),
             (["--csv", "--out", "spec.toml"], "spec.toml", "--out")]
    for opts, path, key in cases:
        code, err = _cli(["export", "r", *opts], capsys)
        line = _one_line(err)
        assert code == 2 and line.startswith(f"hinfnn: ConfigError: {key}: {path} exists and hinfnn did not "
                                             "write it") and "give a new file's path" in line, (opts, line)
    assert Path("notes.csv").read_text() == "mine" and Path("spec.toml").read_text() == "name = 'my sweep'\n"
    assert Path("own/trajectory.csv").read_text() == "mine too"
    assert (r / "trajectory.csv").read_text() == "the user's, not in the marker"
    assert sorted(p.name for p in Path("own").iterdir()) == ["trajectory.csv"]


def test_export_replaces_its_own_file_and_checks_every_format_first(tmp_path, result, capsys):
    r = _copy(result, tmp_path / "r")
    assert _cli(["export", r, "--csv"], capsys)[0] == 0
    first = (r / "trajectory.csv").read_text()
    assert _cli(["export", r, "--csv"], capsys)[0] == 0  # listed in the marker: hinfnn's to replace
    assert (r / "trajectory.csv").read_text() == first and foreign_files(r) == []
    (r / "trajectory.csv").unlink()
    (r / "trajectory.parquet").write_bytes(b"mine")
    code, err = _cli(["export", r, "--csv", "--parquet"], capsys)
    assert code == 2 and "trajectory.parquet" in _one_line(err)
    assert not (r / "trajectory.csv").exists()  # refused before anything was written
    out = tmp_path / "new.csv"
    assert _cli(["export", r, "--csv", "--out", out], capsys)[0] == 0 and out.read_text() == first


def test_export_never_overwrites_a_file_that_appears_while_it_writes(tmp_path, result, monkeypatch):
    from hinfnn.io import export as ex

    out = tmp_path / "t.csv"
    real = ex.csv_text

    def late(*a, **k):
        out.write_text("the user's, saved meanwhile")
        return real(*a, **k)

    monkeypatch.setattr(ex, "csv_text", late)
    with pytest.raises(H.ConfigError, match="appeared while the table was written"):
        ex.export(result, "csv", out=out)
    assert out.read_text() == "the user's, saved meanwhile"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.csv"]


def test_export_and_plot_to_a_broken_link_or_a_read_only_disk_exit_2_naming_it(tmp_path, result, capsys):
    r = _copy(result, tmp_path / "r")
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    code, err = _cli(["export", r, "--csv", "--out", tmp_path / "dangling"], capsys)
    assert code == 2 and "broken symbolic link" in _one_line(err)
    with tmpfs(tmp_path / "ro", read_only=True) as ro:
        for args in (["export", r, "--csv", "--out", ro], ["export", r, "--csv", "--out", ro / "t.csv"],
                     ["plot", r, "--out", ro / "figs"]):
            code, err = _cli(args, capsys)
            line = _one_line(err)
            assert code == 2 and line.startswith("hinfnn: ConfigError: --out: cannot write in") and str(ro) in line
            assert "Read-only file system" in line


def test_plot_into_the_result_folder_keeps_a_figure_the_user_put_there(tmp_path, result, capsys):
    r = _copy(result, tmp_path / "r")
    (r / "u1.png").write_bytes(b"my own figure")
    code, err = _cli(["plot", r, "--figures", "u1"], capsys)
    assert code == 2 and "u1.png" in _one_line(err) and "did not write" in err
    assert (r / "u1.png").read_bytes() == b"my own figure"


# --- commits where a rename cannot work ---------------------------------------------------------------------


def test_run_into_a_mount_point_and_force_over_it_and_over_a_link(tmp_path, capsys):
    with tmpfs(tmp_path / "mnt") as mnt:
        assert _cli(["run", "paper", *TINY, "--out", mnt], capsys)[0] == 0
        assert read_marker(mnt)["files"] == ["metrics.json", "scenario.toml", "trajectory.npz"]
        assert _cli(["run", "paper", *TINY, "--set", "controller.kind=fl", "--out", mnt, "--force"], capsys)[0] == 0
        assert set(H.load(mnt).trajectories) == {"fl"}
        assert sorted(p.name for p in mnt.iterdir()) == [MARKER, "metrics.json", "scenario.toml", "trajectory.npz"]
        link = tmp_path / "link"
        link.symlink_to(mnt)
        assert _cli(["run", "paper", *TINY, "--out", link, "--force"], capsys)[0] == 0
        assert link.is_symlink() and set(H.load(mnt).trajectories) == {"hinf"}
        assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "mnt"]  # no stray hidden link or folder
        assert sorted(p.name for p in mnt.iterdir()) == [MARKER, "metrics.json", "scenario.toml", "trajectory.npz"]


def test_force_on_a_symlinked_folder_keeps_the_link_and_leaves_nothing_stray(tmp_path, result, capsys):
    real = _copy(result, tmp_path / "real")
    link = tmp_path / "link"
    link.symlink_to(real, target_is_directory=True)
    assert _cli(["run", "paper", *TINY, "--set", "controller.kind=fl", "--out", link, "--force"], capsys)[0] == 0
    assert link.is_symlink() and set(H.load(real).trajectories) == {"fl"} and foreign_files(real) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "real"]
    assert not any(p.name.startswith(".") and p.name != MARKER for p in real.iterdir())


def test_a_rename_that_fails_with_ebusy_commits_inside(tmp_path, result, monkeypatch):
    """A mount point os.path.ismount does not see (a bind mount of the same file system): the
    rename fails with EBUSY and the result is committed inside the folder instead."""
    from hinfnn.io import folders

    target = _copy(result, tmp_path / "r")
    (target / "report.md").write_text("old")  # a file of the old result that the new one lacks
    folders.write_marker(target, kind="run", command="")
    new = tmp_path / ".new"
    new.mkdir()
    (new / "metrics.json").write_text("{}")
    folders.write_marker(new, kind="run", command="again")

    def busy(a, b):
        raise OSError(errno.EBUSY, os.strerror(errno.EBUSY), os.fspath(b))

    monkeypatch.setattr(folders, "_exchange", busy)
    folders.replace_folder(new, target)
    assert sorted(p.name for p in target.iterdir()) == [MARKER, "metrics.json"]
    assert read_marker(target)["files"] == ["metrics.json"] and read_marker(target)["command"] == "again"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]


def test_run_gallery_and_sweep_refuse_a_read_only_mount_and_a_broken_link_before_any_work(tmp_path, capsys):
    spec = tmp_path / "spec.toml"
    spec.write_text(textwrap.dedent(SPEC))
    (tmp_path / "dangling").symlink_to(tmp_path / "nowhere")
    with tmpfs(tmp_path / "ro", read_only=True) as ro:
        for out, words in ((ro, "Read-only file system"), (ro / "sub", "Read-only file system"),
                           (tmp_path / "dangling", "broken symbolic link")):
            for args in (["run", "paper", *TINY, "--out", out], ["run", "paper", *TINY, "--out", out, "--force"],
                         ["gallery", "--only", "ur5-table", "--out", out],
                         ["sweep", spec, "--out", out, "--quiet"], ["sweep", spec, "--out", out, "--force", "--quiet"]):
                code, err = _cli(args, capsys)
                line = _one_line(err)
                assert code == 2 and line.startswith("hinfnn: ConfigError: --out: ") and words in line, (args, line)
        assert list(ro.iterdir()) == []
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dangling", "ro", "spec.toml"]


def test_sweep_force_and_resume_in_a_mount_point(tmp_path, capsys):
    spec = tmp_path / "spec.toml"
    spec.write_text(textwrap.dedent(SPEC))
    with tmpfs(tmp_path / "mnt") as mnt:
        assert _cli(["sweep", spec, "--out", mnt, "--batch-size", "2", "--quiet"], capsys)[0] == 0
        first = H.load_sweep(mnt)
        assert _cli(["sweep", spec, "--out", mnt, "--batch-size", "2", "--quiet", "--force"], capsys)[0] == 0
        import pandas as pd

        pd.testing.assert_frame_equal(H.load_sweep(mnt), first, check_exact=True)
        assert not any(p.name.startswith(".hinfnn") for p in mnt.iterdir())
        assert _cli(["sweep", spec, "--out", mnt, "--resume", "--quiet"], capsys)[0] == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["mnt", "spec.toml"]


# --- the marker ---------------------------------------------------------------------------------------------


def test_a_cut_marker_is_still_hinfnn_s_own(tmp_path, result):
    r = _copy(result, tmp_path / "r")
    text = (r / MARKER).read_text()
    (r / MARKER).write_text(text[: len(text) // 2])
    assert foreign_files(r) == []
    reserve_output(r, force=True).release()  # --force still replaces it
    (r / "notes.txt").write_text("mine")
    with pytest.raises(H.ConfigError) as ex:
        reserve_output(r, force=True)
    assert "notes.txt" in str(ex.value) and "damaged" in str(ex.value) and MARKER not in foreign_files(r)


def test_metrics_of_a_newer_format_are_refused(tmp_path, result, capsys):
    r = _copy(result, tmp_path / "r")
    doc = json.loads((r / "metrics.json").read_text())
    doc["format"] = "hinfnn-metrics-99"
    (r / "metrics.json").write_text(json.dumps(doc))
    with pytest.raises(H.LoadError, match="newer hinfnn .*hinfnn-metrics-99"):
        load_metrics(r)
    code, err = _cli(["show", r], capsys)
    assert code == 2 and _one_line(err).startswith("hinfnn: LoadError: ")
    doc["format"] = "other-format-1"
    (r / "metrics.json").write_text(json.dumps(doc))
    with pytest.raises(H.LoadError, match="not a hinfnn metrics file"):
        load_metrics(r)


# --- gallery and sweeps: nothing computed is lost, nothing half-started is refused -------------------------


def test_gallery_only_twice_runs_the_scenario_once():
    from hinfnn.workflows.gallery import gallery_scenarios

    assert [s.name for s in gallery_scenarios(only=["ur5-table", "ur5-table"])] == ["ur5-table"]


def test_sweep_without_pyarrow_exits_2_naming_the_extra_and_creates_nothing(tmp_path, capsys, monkeypatch):
    spec = tmp_path / "spec.toml"
    spec.write_text(textwrap.dedent(SPEC))
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    monkeypatch.setitem(sys.modules, "pyarrow.parquet", None)
    code, err = _cli(["sweep", spec, "--out", tmp_path / "s", "--quiet"], capsys)
    assert code == 2 and "pip install 'hinfnn[sweep]'" in _one_line(err)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["spec.toml"]


def _spec():
    import tomllib

    from hinfnn.sweep import spec_from_dict

    return spec_from_dict(tomllib.loads(textwrap.dedent(SPEC)))


def test_a_full_disk_before_the_first_part_leaves_nothing_resume_refuses(tmp_path, monkeypatch):
    from hinfnn.sweep import run_sweep, store

    spec = _spec()
    real = store.write_table

    def full(*a, **k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(store, "write_table", full)
    with pytest.raises(OSError):
        run_sweep(spec, tmp_path / "s", max_batch=2)
    assert not (tmp_path / "s").exists()  # the folder it made is gone again
    (tmp_path / "empty").mkdir()
    with pytest.raises(OSError):
        run_sweep(spec, tmp_path / "empty", max_batch=2)
    assert list((tmp_path / "empty").iterdir()) == []  # the user's folder is kept, empty
    monkeypatch.setattr(store, "write_table", real)

    def no_parts(folder):
        Path(folder).mkdir(parents=True, exist_ok=True)
        full()

    monkeypatch.setattr(store, "prepare_folder", no_parts)  # the disk fills up at parts/ itself
    with pytest.raises(OSError):
        run_sweep(spec, tmp_path / "s", max_batch=2)
    assert not (tmp_path / "s").exists()
    monkeypatch.undo()
    # killed at that moment instead (nothing cleaned up): --resume starts it
    left = tmp_path / "left"
    (left / store.PARTS).mkdir(parents=True)
    (left / "sweep.toml").write_text(spec.to_toml(resolved=True))
    res = run_sweep(spec, left, resume=True, max_batch=2, report=False)
    assert res.simulated_now == 2 and H.load_sweep(left).attrs["complete"]


def _interrupted_after_one_part(tmp_path):
    """A sweep of two runs interrupted after its first part: (spec, folder)."""
    from hinfnn.sweep import run_sweep

    spec = _spec()
    folder = tmp_path / "s"

    def stop(batch):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_sweep(spec, folder, max_batch=1, on_part=stop)
    return spec, folder


def test_a_damaged_part_says_which_and_that_deleting_it_lets_resume_recompute(tmp_path):
    from hinfnn.sweep import run_sweep, store

    spec, folder = _interrupted_after_one_part(tmp_path)
    part = folder / store.PARTS / store.part_name(0)
    part.write_bytes(part.read_bytes()[:100])
    with pytest.raises(H.LoadError) as ex:
        run_sweep(spec, folder, resume=True, report=False)
    assert str(part) in str(ex.value) and "delete it" in str(ex.value) and "--resume" in str(ex.value)
    part.unlink()
    res = run_sweep(spec, folder, resume=True, report=False)
    assert res.simulated_now == 2 and H.load_sweep(folder).attrs["complete"]


def test_a_cut_plan_is_a_load_error_not_rows(tmp_path):
    from hinfnn.sweep import run_sweep, store

    spec, folder = _interrupted_after_one_part(tmp_path)
    assert len(H.load_sweep(folder)) == 1
    plan = folder / store.PLAN
    plan.write_text(plan.read_text()[:20])
    with pytest.raises(H.LoadError, match="plan.json is damaged"):
        H.load_sweep(folder)
    with pytest.raises(H.LoadError, match="plan.json is damaged"):
        run_sweep(spec, folder, resume=True, report=False)


def test_an_interrupted_command_leaves_no_resource_tracker_warning(tmp_path):
    """An interrupted ``hinfnn`` leaves with os._exit; the semaphores of a sweep's worker queue are
    released first, so that multiprocessing's resource tracker has nothing to warn about."""
    code = textwrap.dedent("""
        import multiprocessing
        from hinfnn import cli
        q = multiprocessing.get_context("spawn").Queue()
        q.put(1)
        q.get()
        cli._interrupted_exit(130, None)
    """)
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       env={**os.environ, "PYTHONPATH": str(SRC)})
    assert p.returncode == 130 and "resource_tracker" not in p.stderr and "leaked" not in p.stderr, p.stderr
