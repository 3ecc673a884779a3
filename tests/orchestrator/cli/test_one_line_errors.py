"""Class 5 of issue 10: every bad input or failing environment is one line, never a
traceback (cli.main + capsys, in-process; each case is a few tenths of a second)."""

import errno
import os
import shutil
import zipfile

import pytest

from agv_cosim import cli, files, timeseries
from agv_cosim import pipeline as runner
from agv_cosim.manifest import whole_multiple
from agv_cosim.pipeline import run as runner_run


def _fail(capsys, argv, code=2):
    got = cli.main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert got == code, err
    assert len(err) == 1 and err[0].startswith("agv-cosim: error: "), err
    return err[0]


def _rewrite_fmu(src, dest, edit):
    """Copy an FMU with its modelDescription.xml changed by ``edit(text)``."""
    with zipfile.ZipFile(src) as old, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as new:
        for info in old.infolist():
            data = old.read(info)
            if info.filename == "modelDescription.xml":
                data = edit(data.decode()).encode()
            new.writestr(info, data)
    return dest


def _corrupt_entry(path, name):
    """Flip bytes inside the deflated data of entry ``name`` (its CRC then fails)."""
    with zipfile.ZipFile(path) as archive:
        info = archive.getinfo(name)
    raw = bytearray(path.read_bytes())
    start = info.header_offset + 30 + len(info.filename.encode()) + len(info.extra)
    middle = start + info.compress_size // 2
    for i in range(middle, middle + 16):
        raw[i] ^= 0x5A
    path.write_bytes(bytes(raw))


def _with_fmu(chain, fmu, name="gain"):
    path = chain()
    text = path.read_text()
    old = next(line for line in text.splitlines() if "AgvTestGain.fmu" in line)
    path.write_text(text.replace(old, f'fmu = "{fmu}"', 1))
    return path


def test_corrupt_deflate_in_fmu(chain, fmus, tmp_path, capsys):
    fmu = tmp_path / "Corrupt.fmu"
    shutil.copy(fmus["agv_test_gain"], fmu)
    with zipfile.ZipFile(fmu) as archive:
        biggest = max(archive.infolist(), key=lambda i: i.compress_size).filename
    _corrupt_entry(fmu, biggest)
    line = _fail(capsys, ["validate", str(_with_fmu(chain, fmu))])
    assert "components.gain.fmu: broken FMU" in line and str(fmu) in line


# the reasons are fmpy's (read_model_description: XML schema, then its own resolution)
@pytest.mark.parametrize("edit, culprit", [
    (lambda t: t.replace('valueReference="0"', "", 1),
     "Element 'ScalarVariable': The attribute 'valueReference' is required but missing"),
    (lambda t: t.replace('valueReference="0"', 'valueReference="zero"', 1),
     "attribute 'valueReference': 'zero' is not a valid value of the atomic type "
     "'xs:unsignedInt'"),
    (lambda t: t.replace('<Unknown index="', '<Unknown index="99', 1),
     "an index or value reference in ModelStructure or Dimension names no variable"),
    (lambda t: t.replace('<Unknown index="', '<Unknown index="x', 1),
     "Element 'Unknown', attribute 'index': 'x"),
    (lambda t: t.replace('fmiVersion="2.0"', 'fmiVersion="1.0"', 1),
     "not an FMI 2.0 or 3.0 FMU (fmiVersion='1.0')"),
])
def test_broken_model_description(chain, fmus, tmp_path, capsys, edit, culprit):
    fmu = _rewrite_fmu(fmus["agv_test_gain"], tmp_path / "Edited.fmu", edit)
    line = _fail(capsys, ["validate", str(_with_fmu(chain, fmu))])
    assert "components.gain.fmu: " in line and str(fmu) in line
    assert culprit in line


@pytest.mark.parametrize("stop, step, culprit", [
    ("1e300", "1e-10", "steps; at most"),           # OverflowError before
    ("500000.5", "1.0", "is not a whole number of steps"),  # relative check before
])
def test_step_count(chain, capsys, stop, step, culprit):
    path = chain(stop=stop, step=step)
    line = _fail(capsys, ["validate", str(path)])
    assert "simulation.step: " in line and culprit in line


def test_whole_multiple():
    assert whole_multiple(20.0, 0.001) and whole_multiple(10.0, 0.01)
    assert whole_multiple(2.0 ** 40, 1.0) and not whole_multiple(2.0 ** 40 + 0.5, 1.0)
    assert not whole_multiple(500000.5, 1.0) and not whole_multiple(0.5, 1.0)


def test_integer_out_of_range(fmus, tmp_path, capsys):
    path = tmp_path / "pair.toml"
    path.write_text(f'[simulation]\nstop = 1.0\nstep = 0.5\n[components.a]\n'
                    f'fmu = "{fmus["agv_test_pair"]}"\n'
                    'parameters = { n = 99999999999999999999 }\n')
    line = _fail(capsys, ["validate", str(path)])
    assert "components.a.parameters.n: 'a.n' = 99999999999999999999 is out of the range" in line


PAIR = """
[simulation]
stop = 1.0
step = 0.5
algorithm = "{algorithm}"
[components.a]
fmu = "{fmu}"
parameters = {{ n = 2 }}
[components.b]
fmu = "{fmu}"
[[connections]]
from = "a.y1"
to = "b.u1"
[[connections]]
from = "b.y2"
to = "a.u2"
"""


def test_jacobi_accepts_a_component_level_cycle(fmus, tmp_path, capsys):
    """a -> b and b -> a through feedthrough outputs, no loop between variables: Jacobi
    needs no order and runs it; Gauss-Seidel refuses it (and then suggests Jacobi)."""
    path = tmp_path / "pair.toml"
    path.write_text(PAIR.format(algorithm="gauss-seidel", fmu=fmus["agv_test_pair"]))
    line = _fail(capsys, ["validate", str(path)])
    # the cycle is named (graphlib's CycleError, started at the first component)
    assert "components a -> b -> a feed each other" in line
    assert "use algorithm = 'jacobi'" in line
    path.write_text(PAIR.format(algorithm="jacobi", fmu=fmus["agv_test_pair"]))
    assert cli.main(["validate", str(path)]) == 0


def test_bad_reference_path_is_refused_before_running(chain, capsys):
    path = chain(extra='[metrics]\nreference = { path = "sine:amplitude=oops", '
                       'x = "int.y", y = "int.y" }\n')
    line = _fail(capsys, ["run", str(path), "--quiet", "--out", str(path.parent / "o")])
    number = path.read_text().splitlines().index("[metrics]") + 2
    assert f"{path}:{number}: metrics.reference.path: " in line
    assert not (path.parent / "o").exists()


def test_export_ssp_onto_a_folder(chain, tmp_path, capsys):
    (tmp_path / "folder.ssp").mkdir()
    line = _fail(capsys, ["export-ssp", str(chain()), "-o", str(tmp_path / "folder.ssp")])
    assert "folder.ssp: is a folder" in line


def test_corrupt_ssp(chain, tmp_path, capsys):
    out = tmp_path / "c.ssp"
    assert cli.main(["export-ssp", str(chain()), "-o", str(out)]) == 0
    capsys.readouterr()
    _corrupt_entry(out, "SystemStructure.ssd")
    line = _fail(capsys, ["validate", str(out)])
    assert f"{out}: archive: not a readable zip archive" in line


def test_full_disk_is_one_line(chain, tmp_path, capsys, monkeypatch):
    """ENOSPC while writing a run (the disk fills after the header) is that run's
    failure naming the file, not an FMU's; ENOSPC in the parent is one line, exit 1."""
    _, jobs, _ = runner.prepare(chain(stop=2.0, step=0.001))
    run_dir = tmp_path / "run"
    written = []

    def filling(sink, data):
        if written:  # the header went in; the disk is full from the first row on
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        written.append(data)
        os.write(sink.fd, data)

    with monkeypatch.context() as patch:
        patch.setattr(timeseries.CsvSink, "_write", filling)
        result = runner.run_job(jobs[0], run_dir)
    assert result["status"] != "complete"
    assert "No space left on device" in result["error"] and "component" not in result["error"]
    assert str(run_dir / "timeseries.csv") in result["error"]

    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device", "summary.csv")

    monkeypatch.setattr(runner_run, "write_summary", full)
    line = _fail(capsys, ["run", str(chain()), "--quiet", "--out", str(tmp_path / "o")],
                 code=1)
    assert line == "agv-cosim: error: summary.csv: No space left on device"
    assert not (tmp_path / "o").exists()
    assert files.is_result_folder(tmp_path) is False
