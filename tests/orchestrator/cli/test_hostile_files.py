"""Hostile round three, file system: only what carries our marker is cleaned, nothing is
written through a symbolic link, a result folder removed during the run is never passed
off as complete, temporary folders are private."""

import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from agv_cosim import cli, errors, lifetime
from agv_cosim import files as results
from agv_cosim import pipeline as runner
from agv_cosim.errors import OutputError
from agv_cosim.files import MARKER, AtomicDir
from agv_cosim.workers import pool


def _run(path, out, *extra):
    return cli.main(["run", str(path), "--out", str(out), "--quiet", *extra])


def _last_error(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert err, "nothing on stderr"
    return err[-1]


def _dead_pid():
    """A pid no process has now (a child that has been reaped)."""
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    child.wait()
    return child.pid


# ---------------------------------------------------------------- the stale cleaner

def test_the_cleaner_keeps_user_folders_whose_names_look_like_ours(tmp_path):
    """Folders named like ours without our marker are never removed, whatever pid their
    name holds; a folder of ours whose process is gone is."""
    user = [tmp_path / "agv-cosim-2024-thesis-backup", tmp_path / "agv-cosim-4000000-notes"]
    for folder in user:
        folder.mkdir()
        (folder / "chapter1.tex").write_text("years of work")
    fake = tmp_path / f"agv-cosim-{_dead_pid()}-run-abcdefgh"  # our name, a marker
    fake.mkdir()                                               # that is not ours
    (fake / lifetime.SCRATCH_MARKER).write_text("{}")
    linked = tmp_path / f"agv-cosim-{_dead_pid()}-run-linked00"  # the marker a link
    linked.mkdir()
    (linked / lifetime.SCRATCH_MARKER).symlink_to(tmp_path / "elsewhere.json")
    (tmp_path / "elsewhere.json").write_text(json.dumps({"tool": "agv-cosim",
                                                         "pid": _dead_pid()}))
    ours = Path(lifetime.scratch_dir("run"))
    try:
        marker = json.loads((ours / lifetime.SCRATCH_MARKER).read_text())
        marker["pid"] = _dead_pid()
        (ours / lifetime.SCRATCH_MARKER).write_text(json.dumps(marker))
        stale = tmp_path / ours.name
        ours.rename(stale)
        assert lifetime.clean_stale_scratch(tmp_path) == 1
        assert not stale.exists()
        for folder in user:
            assert (folder / "chapter1.tex").read_text() == "years of work"
        assert fake.exists() and linked.exists()
    finally:
        if ours.exists():
            ours.rename(tmp_path / "leftover")


def test_the_cleaner_keeps_live_folders_and_tells_a_reused_pid(tmp_path):
    """A marker naming a live process is kept; one naming a live pid with another start
    time (the pid was reused) is stale."""
    live = Path(lifetime.scratch_dir("run"))
    try:
        moved = tmp_path / live.name
        live.rename(moved)
        assert lifetime.clean_stale_scratch(tmp_path) == 0 and moved.exists()
        parent = os.getppid()  # alive, but it did not make this folder
        reused = tmp_path / f"agv-cosim-{parent}-run-reused00"
        reused.mkdir()
        (reused / lifetime.SCRATCH_MARKER).write_text(json.dumps(
            {"tool": "agv-cosim", "pid": parent, "start": 1}))
        assert lifetime.clean_stale_scratch(tmp_path) == 1
        assert not reused.exists() and moved.exists()
    finally:
        for folder in tmp_path.glob("agv-cosim-*"):
            folder.rename(tmp_path / f"done-{folder.name}")


def test_scratch_folders_and_fmu_extractions_are_private(fmus, tmp_path, monkeypatch):
    """Scratch folders are 0700 and carry the marker (a regular file, not a link); an
    FMU's extraction (binaries/ included) is readable by its user only."""
    from agv_cosim.execution import instance as model
    from agv_cosim.system import read_model

    folder = Path(lifetime.scratch_dir("run"))
    try:
        assert stat.S_IMODE(folder.stat().st_mode) == 0o700
        marker = folder / lifetime.SCRATCH_MARKER
        assert marker.is_file() and not marker.is_symlink()
        assert json.loads(marker.read_text())["pid"] == os.getpid()
    finally:
        import shutil

        shutil.rmtree(folder)
    monkeypatch.setattr(model, "_EXTRACT_ROOT", [])
    monkeypatch.setattr(model, "_EXTRACTED", {})
    monkeypatch.setattr(model.tempfile, "tempdir", str(tmp_path))
    old = os.umask(0o022)
    try:
        instance = model.FmuInstance(read_model(fmus["agv_test_gain"]), "g")
        try:
            entries = list(Path(instance.unzip_dir).rglob("*"))
            assert any(p.parts[-3:-1] == ("binaries", "linux64") for p in entries)
            for entry in entries + [Path(instance.unzip_dir)]:
                assert stat.S_IMODE(entry.stat().st_mode) & 0o077 == 0, entry
        finally:
            instance.close()
    finally:
        os.umask(old)


# ---------------------------------------------------------------- locks and links

@pytest.mark.parametrize("dangling", [False, True])
def test_a_symlinked_lock_file_is_refused_not_followed(chain, tmp_path, capsys, dangling):
    """The lock file .<out>.lock is a link to a user's file (or to where none is yet):
    the run refuses with one line, the file is untouched (or not created)."""
    victim = tmp_path / "thesis.tex"
    if not dangling:
        victim.write_text("years of work")
    (tmp_path / ".out.lock").symlink_to(victim)
    assert _run(chain(), tmp_path / "out") == 2
    line = _last_error(capsys)
    assert line.startswith("agv-cosim: error: ") and "symbolic link" in line
    assert ".out.lock" in line
    if dangling:
        assert not victim.exists()
    else:
        assert victim.read_text() == "years of work"
    assert not (tmp_path / "out").exists()


def test_a_lock_that_is_not_a_regular_file_is_refused(tmp_path):
    os.mkfifo(tmp_path / ".out.lock")
    with pytest.raises(OutputError, match="not a regular file"):
        AtomicDir(tmp_path / "out")


def test_files_are_never_written_through_a_planted_link(chain, tmp_path):
    """A link planted where a run's file will go makes that run fail (O_EXCL |
    O_NOFOLLOW): the file it points to is untouched."""
    _, jobs, _ = runner.prepare(chain())
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    (run_dir / "timeseries.csv").symlink_to(victim)
    with pytest.raises(FileExistsError):
        runner.run_job(jobs[0], run_dir)
    assert victim.read_text() == "keep me"
    with pytest.raises(OSError):
        results.write_json(run_dir / "timeseries.csv", {"a": 1})
    with pytest.raises(OSError):
        with results.open_output(run_dir / "timeseries.csv"):
            pass
    assert victim.read_text() == "keep me"


def test_an_old_name_we_pick_is_never_a_users_folder(chain, tmp_path):
    """Replacing our result folder renames it onto a fresh folder of our own: a user's
    folder named like the old name of earlier versions (.<out>.old-<pid>) is kept."""
    out = tmp_path / "res"
    assert _run(chain(), out) == 0
    user = tmp_path / f".res.old-{os.getpid()}"
    user.mkdir()
    (user / "notes.txt").write_text("mine")
    assert _run(chain(), out) == 0
    assert (user / "notes.txt").read_text() == "mine"


# ---------------------------------------------------------------- folders removed mid-run

def test_a_result_folder_removed_before_the_summary_is_one_line(chain, tmp_path, capsys,
                                                                 monkeypatch):
    """The hidden folder being written is removed while the runs go on: no summary
    claims complete runs, one line names the folder, exit 1, nothing half-written."""
    import shutil

    real = pool.run_isolated

    def runs_then_removed(jobs, root, *args, **kwargs):
        done = real(jobs, root, *args, **kwargs)
        shutil.rmtree(root)
        return done

    monkeypatch.setattr(pool, "run_isolated", runs_then_removed)
    assert _run(chain(), tmp_path / "out") == 1
    line = _last_error(capsys)
    assert line.startswith(f"agv-cosim: error: {tmp_path / 'out'}: the folder being "
                           "written") and "was removed or replaced during the run" in line
    assert sorted(p.name for p in tmp_path.iterdir()) == ["chain.toml"]


def test_a_result_folder_whose_parent_is_removed_is_one_line(chain, tmp_path, capsys,
                                                             monkeypatch):
    import shutil

    real = pool.run_isolated

    def runs_then_parent_removed(jobs, root, *args, **kwargs):
        done = real(jobs, root, *args, **kwargs)
        shutil.rmtree(root.parent)
        return done

    monkeypatch.setattr(pool, "run_isolated", runs_then_parent_removed)
    assert _run(chain(), tmp_path / "deep" / "out") == 1
    assert "was removed or replaced during the run" in _last_error(capsys)
    assert not (tmp_path / "deep").exists()  # not recreated by us


def test_a_run_folder_removed_after_its_run_is_not_complete(chain, tmp_path, capsys,
                                                            monkeypatch):
    """One run's folder is removed after it completed: summary.csv says it failed and
    why, the other run stays complete."""
    import shutil

    real = pool.run_isolated

    def one_removed(jobs, root, *args, **kwargs):
        done = real(jobs, root, *args, **kwargs)
        shutil.rmtree(root / jobs[0].label)
        return done

    monkeypatch.setattr(pool, "run_isolated", one_removed)
    path = chain(extra='[sweep]\n"gain.k" = [1.0, 2.0]\n')
    assert _run(path, tmp_path / "out") == 1
    err = capsys.readouterr().err
    assert "its folder was removed or changed during the sweep" in err
    summary = (tmp_path / "out" / "summary.csv").read_text().splitlines()
    assert summary[1].startswith("base__gain.k=1.0,,failed")
    assert summary[2].startswith("base__gain.k=2.0,,complete")


def test_the_runs_folder_is_not_recreated_by_a_worker(chain, tmp_path):
    """run_job makes the run's folder but never its parents."""
    _, jobs, _ = runner.prepare(chain())
    with pytest.raises(FileNotFoundError):
        runner.run_job(jobs[0], tmp_path / "gone" / "run")
    assert not (tmp_path / "gone").exists()


def test_commit_checks_the_folder_is_still_ours(tmp_path):
    folder = AtomicDir(tmp_path / "out")
    try:
        assert folder.intact()
        (folder.path / MARKER).unlink()
        (folder.path / MARKER).write_text("{}")  # replaced by something not ours
        assert not folder.intact()
        with pytest.raises(errors.FolderLost, match="removed or replaced"):
            folder.commit()
    finally:
        folder.discard()
    assert not (tmp_path / "out").exists()
