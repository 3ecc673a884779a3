"""Class 1 of issue 10: the orchestrator replaces only what it wrote.

A result folder is replaced only when it carries our marker (or is empty); anything else
is refused with one line naming the path (exit 2) unless --overwrite; a file is never
replaced. Names from manifests are single path components; run labels are bounded;
stale .incomplete folders are cleaned; folders get the user's umask; one run per --out.
"""

import os
import stat
from pathlib import Path

import pytest

from agv_cosim import cli
from agv_cosim.errors import OutputError
from agv_cosim.files import MARKER, AtomicDir, check_name
from agv_cosim.plan import MAX_LABEL, run_label


def _run(path, out, *extra):
    return cli.main(["run", str(path), "--out", str(out), "--quiet", *extra])


def _one_error(capsys):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("agv-cosim: error: "), err
    return err[0]


def test_user_folder_is_refused_unless_overwrite(chain, tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "thesis.tex").write_text("years of work")
    assert _run(chain(), out) == 2
    line = _one_error(capsys)
    assert str(out) in line and "not a result folder" in line and "--overwrite" in line
    assert (out / "thesis.tex").read_text() == "years of work"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no leftovers
    assert _run(chain(), out, "--overwrite") == 0
    assert (out / "summary.csv").is_file() and not (out / "thesis.tex").exists()


def test_our_folder_and_empty_folder_are_replaced(chain, tmp_path):
    out = tmp_path / "res"
    assert _run(chain(), out) == 0
    assert (out / MARKER).is_file()
    first = (out / "base" / "run.json").stat().st_ino
    (out / "base" / "stale.txt").write_text("a file agv-cosim did not write")
    assert _run(chain(), out) == 0  # ours: replaced
    assert (out / "base" / "run.json").stat().st_ino != first  # written anew
    # a file this tool did not write is never deleted (test_resume_hostile.py)
    assert (out / "base" / "stale.txt").read_text() == "a file agv-cosim did not write"
    empty = tmp_path / "empty"
    empty.mkdir()
    assert _run(chain(), empty) == 0


def test_file_is_never_replaced(chain, tmp_path, capsys):
    target = tmp_path / "notes.txt"
    target.write_text("keep me")
    for extra in ((), ("--overwrite",)):
        assert _run(chain(), target, *extra) == 2
        assert "exists and is not a folder" in _one_error(capsys)
        assert target.read_text() == "keep me"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["chain.toml", "notes.txt"]


def test_out_under_a_file_or_unwritable(chain, tmp_path, capsys):
    (tmp_path / "plain").write_text("x")
    assert _run(chain(), tmp_path / "plain" / "out") == 2
    assert "is not a folder" in _one_error(capsys)
    if Path("/proc/self").is_dir():  # a place nobody can write, not even root
        assert _run(chain(), "/proc/agv-cosim-out") == 2
        assert "/proc/agv-cosim-out: cannot write here" in _one_error(capsys)
    if os.geteuid() == 0:
        return  # root writes everywhere else
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    assert _run(chain(), locked / "out") == 2
    assert "cannot" in _one_error(capsys)


@pytest.mark.parametrize("name", ["..", "", ".", "/tmp/x", "a/b", ".hidden", "x" * 200])
def test_manifest_name_is_one_path_component(chain, tmp_path, capsys, monkeypatch, name):
    path = chain()
    path.write_text(path.read_text().replace('name = "chain"', f'name = "{name}"'))
    (tmp_path / "precious").write_text("data")
    monkeypatch.chdir(tmp_path)  # the default --out is results/<name>
    assert cli.main(["run", str(path), "--quiet"]) == 2
    line = _one_error(capsys)
    assert f"{path}:2: name: " in line  # name = ... on line 2 of the chain manifest
    assert (tmp_path / "precious").read_text() == "data"
    assert not (tmp_path / "results").exists()


def test_variant_name_is_one_path_component(chain, capsys):
    path = chain(extra='[variants."..".components.gain]\nparameters = { k = 9.0 }\n')
    assert cli.main(["validate", str(path)]) == 2
    assert "variants...: variant name '..'" in _one_error(capsys)


def test_long_labels_are_bounded_and_distinct(chain, tmp_path):
    variant = "v" * 120
    path = chain(extra=f'[variants.{variant}.components.gain]\nparameters = {{ k = 9.0 }}\n'
                       '[sweep]\n"gain2.k" = [0.5, 0.25]\n')
    assert _run(chain(extra="", name="c.toml"), tmp_path / "warm") == 0
    assert _run(path, tmp_path / "long") == 0
    runs = sorted(p.name for p in (tmp_path / "long").iterdir() if p.is_dir())
    assert len(runs) == 2 and all(len(r) <= MAX_LABEL for r in runs)
    assert run_label(["a", "b"]) == "a__b"  # short labels unchanged


def test_stale_incomplete_is_cleaned_and_umask_kept(chain, tmp_path):
    stale = tmp_path / ".res.incomplete-dead1234"
    stale.mkdir()
    (stale / MARKER).write_text('{"tool": "agv-cosim", "version": "0.1.0"}\n')
    foreign = tmp_path / ".res.incomplete-notours"  # no marker: not ours, kept
    foreign.mkdir()
    faked = tmp_path / ".res.old-1234"  # a file of that name that is not our marker
    faked.mkdir()
    (faked / MARKER).write_text("{}")
    old = os.umask(0o027)
    try:
        assert _run(chain(), tmp_path / "res") == 0
    finally:
        os.umask(old)
    assert not stale.exists() and foreign.exists() and faked.exists()
    assert stat.S_IMODE((tmp_path / "res").stat().st_mode) == 0o750
    assert not (tmp_path / ".res.lock").exists()


def test_second_run_to_the_same_out_refuses(chain, tmp_path, capsys):
    holder = AtomicDir(tmp_path / "res")  # a run in progress holds the lock
    try:
        assert _run(chain(), tmp_path / "res") == 2
        line = _one_error(capsys)
        assert "another agv-cosim run is writing" in line and f"process {os.getpid()}" in line
        with pytest.raises(OutputError):
            AtomicDir(tmp_path / "res")
    finally:
        holder.discard()
    assert _run(chain(), tmp_path / "res") == 0


def test_check_name():
    assert check_name("seed000_models_abc") == "seed000_models_abc"
    for bad in ("..", ".", "", "a b", "a/b", "a]", ".x", "x" * 129, None):
        with pytest.raises(ValueError):
            check_name(bad)


def test_legacy_result_folder_is_recognised(tmp_path):
    """A folder written before the stamp existed (summary.csv, run folders with
    run.json, plots) is ours; one more file of the user's makes it not ours."""
    from agv_cosim.files import is_result_folder

    old = tmp_path / "old"
    (old / "base").mkdir(parents=True)
    (old / "summary.csv").write_text("run\nbase\n")
    (old / "base" / "run.json").write_text("{}")
    (old / "trajectory.png").write_bytes(b"png")
    assert is_result_folder(old)
    (old / "notes.txt").write_text("mine")
    assert not is_result_folder(old)
    (old / "notes.txt").unlink()
    (old / "data").mkdir()  # a folder without run.json is not a run of ours
    assert not is_result_folder(old)
