"""Sweeps and variants: cartesian product, serial == parallel byte for byte."""

import csv
import json
import os
import zipfile
from pathlib import Path

import pytest

from agv_cosim import cli

from result_folders import folder_contents

SWEEP = """
[variants.one.components.gain2]
parameters = { k = 1.0 }
[variants.two.components.gain2]
parameters = { k = 2.0 }
[sweep]
"gain.k" = [1.0, 2.0]
"src.slope" = [0.5, 1.5]
"""


@pytest.mark.slow  # seconds: builds or runs FMUs in processes
def test_sweep_serial_equals_parallel(chain, tmp_path):
    path = chain(extra=SWEEP)
    assert cli.main(["run", str(path), "--out", str(tmp_path / "s"), "--jobs", "1",
                     "--quiet"]) == 0
    assert cli.main(["run", str(path), "--out", str(tmp_path / "p"), "--jobs", "2",
                     "--quiet"]) == 0
    # every file but timings.csv (the wall times) the same, byte for byte
    serial, parallel = folder_contents(tmp_path / "s"), folder_contents(tmp_path / "p")
    assert sorted(serial) == sorted(parallel)
    assert sum(name.endswith(".csv") for name in serial) == 2 * 4 + 1  # runs + summary
    for name in serial:
        assert serial[name] == parallel[name], name
    rows = list(csv.DictReader(open(tmp_path / "s" / "summary.csv")))
    assert [r["run"] for r in rows][:2] == ["one__gain.k=1.0__src.slope=0.5",
                                           "one__gain.k=1.0__src.slope=1.5"]
    # final integrator value of run two, k=2, slope=1.5: closed form of the GS chain
    # y(1) = h K (a n + b h n (n-1)/2), K = 2 * 2, a = 1, b = 1.5, n = 10, h = 0.1
    last = (tmp_path / "s" / "two__gain.k=2.0__src.slope=1.5" / "timeseries.csv"
            ).read_text().strip().splitlines()[-1].split(",")
    assert abs(float(last[-1]) - 0.1 * 4 * (10 + 1.5 * 0.1 * 45)) < 1e-12
    info = json.loads((tmp_path / "s" / "two__gain.k=2.0__src.slope=1.5" / "run.json"
                       ).read_text())
    assert info["parameters"]["gain2"]["k"] == 2.0 and info["parameters"]["gain"]["k"] == 2.0
    assert info["status"] == "complete" and len(info["fmu_sha256"]) == 4


def test_set_override_and_variant_selection(chain, tmp_path):
    """--set gain.k=4 and --variant two: one run, K = 4 * 2 = 8, y(1) = 0.1 * 8 * 19."""
    path = chain(extra=SWEEP.split("[sweep]")[0])
    assert cli.main(["run", str(path), "--out", str(tmp_path / "o"), "--variant", "two",
                     "--set", "gain.k=4", "--quiet"]) == 0
    assert [p.name for p in (tmp_path / "o").iterdir() if p.is_dir()] == ["two"]
    last = (tmp_path / "o" / "two" / "timeseries.csv").read_text().strip().splitlines()[-1]
    assert abs(float(last.split(",")[-1]) - 0.1 * 8 * (10 + 2 * 0.1 * 45)) < 1e-12


def test_list(fmus, capsys):
    """Each variable with its causality, value reference (what a host passes to
    fmi2GetReal and the like), type, name, start, unit, description."""
    from fmpy import read_model_description

    assert cli.main(["list", str(fmus["agv_test_gain"])]) == 0
    out = capsys.readouterr().out
    vr = {v.name: f"vr={v.valueReference}"
          for v in read_model_description(str(fmus["agv_test_gain"])).modelVariables}
    assert f"output    {vr['y']:<6} Real    y [1]  k * u  (feedthrough from u)" in out
    assert f"input     {vr['u']:<6} Real    u = 0.0 [1]  Input" in out
    assert f"parameter {vr['k']:<6} Real    k = 1.0 [1]  Gain" in out
    assert "tunable" not in out  # AgvTestGain's k is a fixed parameter


def test_list_marks_tunable_parameters(tmp_path, capsys):
    from agv_cosim.build import build_one, default_components_dir

    # AgvTotalStation's 'available' is its one tunable parameter (a dropout event sets it)
    source = next(default_components_dir().rglob("agv_total_station.py"))
    fmu = build_one(source, tmp_path).fmu
    assert cli.main(["list", str(fmu)]) == 0
    lines = capsys.readouterr().out.splitlines()
    tunable = [line.split()[3] for line in lines if "(tunable" in line]
    assert tunable == ["available"]
    assert all(line.split()[0] == "parameter" for line in lines if "(tunable" in line)


def test_a_worker_is_reused_only_after_complete_runs(fmus, tmp_path, monkeypatch):
    """--jobs 1, three runs: complete, partial (the FMU fails at t = 0.5), complete. The
    first worker takes runs 1 and 2 and exits after the failure; a fresh worker takes run
    3. Counted by the run scratch folders the parent makes, one per worker process."""
    from agv_cosim.workers import pool as runner

    made = []
    real = runner.scratch_dir

    def counting(kind):
        made.append(kind)
        return real(kind)

    monkeypatch.setattr(runner, "scratch_dir", counting)
    text = f"""
name = "reuse"
[simulation]
stop = 1.0
step = 0.1
[components.src]
fmu = "{fmus['agv_test_source']}"
[components.bad]
fmu = "{fmus['agv_test_fail']}"
[[connections]]
from = "src.y"
to = "bad.u"
[sweep]
"bad.fail_time" = [5.0, 0.5, 9.0]
"""
    path = tmp_path / "reuse.toml"
    path.write_text(text)
    assert cli.main(["run", str(path), "--out", str(tmp_path / "all"), "--jobs", "1",
                     "--quiet"]) == 1
    assert made.count("run") == 2
    statuses = [r["status"] for r in csv.DictReader(open(tmp_path / "all" / "summary.csv"))]
    assert statuses == ["complete", "partial", "complete"]
    # run 1 (fresh worker) and run 3 (the fresh worker after the failure) record the
    # same signals (neither fails before the stop): the same bytes
    first, third = (tmp_path / "all" / f"base__bad.fail_time={v}" / "timeseries.csv"
                    for v in ("5.0", "9.0"))
    assert first.read_bytes() == third.read_bytes()


def test_kept_extraction_gives_each_instance_its_own_binary_and_links(fmus, tmp_path,
                                                                      monkeypatch):
    """With keep_extractions (what a worker does), an FMU is unpacked once; every instance
    gets a folder of its own holding this platform's binaries as hard links to that copy
    (a library path of its own: globals of its own) and every other entry as a symbolic
    link to it; both instances instantiate from there, and closing one leaves the other's
    folder and the kept copy in place. Without it, each instance unpacks the archive (no
    shared files)."""
    import fmpy

    from agv_cosim.execution import instance as model
    from agv_cosim.system import read_model

    monkeypatch.setattr(model, "_EXTRACT_ROOT", [])
    monkeypatch.setattr(model, "_EXTRACTED", {})
    info = read_model(fmus["agv_test_gain"])
    monkeypatch.setattr(model.tempfile, "tempdir", str(tmp_path))

    def files(folder):
        return sorted(p for p in Path(folder).rglob("*") if p.is_file())

    plain = model.FmuInstance(info, "plain")
    try:
        assert all(p.stat().st_nlink == 1 and not p.is_symlink()
                   for p in files(plain.unzip_dir))
    finally:
        plain.close()

    model.keep_extractions(str(tmp_path))
    one, two = model.FmuInstance(info, "one"), model.FmuInstance(info, "two")
    platform = Path("binaries", fmpy.platform)
    try:
        [kept] = model._EXTRACTED.values()
        for instance in (one, two):
            own = Path(instance.unzip_dir)
            assert own != Path(kept)
            binaries = sorted(p.relative_to(own) for p in (own / platform).iterdir())
            assert binaries == sorted(p.relative_to(kept)
                                      for p in (Path(kept) / platform).iterdir())
            assert binaries and all(not (own / b).is_symlink() and (own / b).is_file()
                                    and (own / b).samefile(Path(kept) / b)
                                    for b in binaries)
            assert not (own / "binaries").is_symlink()
            others = sorted(p.name for p in own.iterdir() if p.name != "binaries")
            assert others == sorted(p.name for p in Path(kept).iterdir()
                                    if p.name != "binaries")
            assert "resources" in others and "modelDescription.xml" in others
            assert all((own / n).is_symlink() and (own / n).resolve() == Path(kept, n)
                       for n in others)
        one.close()
        assert not Path(kept, platform).is_symlink() and files(kept)
        assert files(Path(two.unzip_dir) / platform) and files(kept)
    finally:
        two.close()
    assert files(kept)


def test_extract_ahead_unpacks_each_fmu_once_privately_and_leaves_a_bad_one(fmus, tmp_path,
                                                                           monkeypatch):
    """extract_ahead (threads) keeps one private extraction per FMU, the same files as
    one unpacked alone, and the process's umask as it was; an archive that does not
    unpack is not kept: its instance unpacks it again and reports the error."""
    import stat

    from agv_cosim.execution import instance as model
    from agv_cosim.system import read_model

    monkeypatch.setattr(model, "_EXTRACT_ROOT", [])
    monkeypatch.setattr(model, "_EXTRACTED", {})
    monkeypatch.setattr(model.tempfile, "tempdir", str(tmp_path))
    infos = [read_model(fmus[name]) for name in ("agv_test_gain", "agv_test_source")]
    broken = tmp_path / "broken.fmu"
    broken.write_bytes(fmus["agv_test_gain"].read_bytes())
    bad = read_model(broken)
    broken.write_bytes(b"PK no longer a zip archive")
    model.keep_extractions(str(tmp_path))
    old = os.umask(0o022)
    try:
        model.extract_ahead([*infos, infos[0], bad])
        assert os.umask(0o022) == 0o022
    finally:
        os.umask(old)
    assert sorted(model._EXTRACTED) == sorted((str(i.path), i.sha256) for i in infos)
    for info in infos:
        kept = Path(model._EXTRACTED[(str(info.path), info.sha256)])
        alone = tmp_path / f"alone-{info.identifier}"
        with zipfile.ZipFile(info.path) as archive:
            archive.extractall(alone)
        assert ({p.relative_to(kept): p.read_bytes() for p in kept.rglob("*") if p.is_file()}
                == {p.relative_to(alone): p.read_bytes() for p in alone.rglob("*")
                    if p.is_file()})
        for entry in [kept, *kept.rglob("*")]:
            assert stat.S_IMODE(entry.stat().st_mode) & 0o077 == 0, entry
    assert len(list(tmp_path.glob("agv_cosim_fmu_*"))) == 2  # the bad one's removed
    with pytest.raises(zipfile.BadZipFile):
        model.FmuInstance(bad, "bad")


def test_a_bar_drawn_only_through_its_postfix_ends_its_line_on_close():
    """A run that ends before the bar's delay redraws it through set_postfix; the message
    printed after close starts on a line of its own (tqdm alone leaves the line open)."""
    import io

    from agv_cosim.pipeline.run import progress_bar

    stream = io.StringIO()
    bar = progress_bar()(total=10, desc="m", delay=2.0, file=stream)
    bar.update(1)
    bar.set_postfix(runs="1/1")
    bar.close()
    text = stream.getvalue()
    assert text.endswith("\n") and "runs=1/1]" in text.splitlines()[-1]

    quiet = io.StringIO()
    bar = progress_bar()(total=10, desc="m", delay=2.0, file=quiet)
    bar.update(1)
    bar.close()
    assert quiet.getvalue() == ""  # never drawn: nothing written
