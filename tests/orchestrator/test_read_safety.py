"""Hostile round four, reading: every file the tool reads (report, --resume, the API,
manifests, SSP packages, FMU hashes) is opened without blocking, must be a regular file
and is read whole only up to the limit of its kind; a FIFO, a device or a file too large
is refused with one line naming it. The commands run in a subprocess with a time limit
(and a memory limit), so that a case that would hang or exhaust memory fails instead."""

import json
import os
import re
import resource
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import agv_cosim
from agv_cosim import cli, files

#: seconds a command that must not block may take (a FIFO blocked it forever before)
LIMIT = 120
#: address space of such a command [bytes]: reading /dev/zero runs into it at once
MEMORY = 3 << 30


def _limit_memory():
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY, MEMORY))


def _command(*args, cwd=None):
    """``agv-cosim args`` in a subprocess with a time and a memory limit: (exit code,
    the lines on stderr)."""
    done = subprocess.run([sys.executable, "-m", "agv_cosim.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=LIMIT, cwd=cwd,
                          preexec_fn=_limit_memory)
    return done.returncode, done.stderr.strip().splitlines()


@pytest.fixture
def results(chain, tmp_path):
    """A result folder of two runs (a sweep), written by ``agv-cosim run``."""
    manifest = chain(extra='[sweep]\n"gain.k" = [1.0, 2.0]\n')
    out = tmp_path / "out"
    assert cli.main(["run", str(manifest), "--out", str(out), "--quiet"]) == 0
    return manifest, out


def _edit_run_json(run_json, **changes):
    record = json.loads(run_json.read_text())
    for key, value in changes.items():
        if isinstance(value, dict):
            record[key].update(value)
        else:
            record[key] = value
    run_json.write_text(json.dumps(record))


def _zero(path):
    os.symlink("/dev/zero", path)


@pytest.mark.parametrize("command, name, make", [
    ("report", "run.json", os.mkfifo), ("report", "run.json", _zero),
    ("report", "metrics.json", _zero),
    ("resume", "run.json", os.mkfifo), ("resume", "run.json", _zero),
])
def test_a_record_that_is_not_a_regular_file_is_refused(results, command, name, make):
    """A run.json or metrics.json that is a FIFO (it hung the command) or a link to
    /dev/zero (read until memory ran out: an internal error) is refused before any
    read: one line naming it, exit 2."""
    manifest, out = results
    run = sorted(p for p in out.iterdir() if p.is_dir())[0]
    (run / name).unlink()
    make(run / name)
    kind = "a FIFO" if (run / name).is_fifo() else "a device"
    if command == "report":
        code, lines = _command("report", out)
    else:  # --resume computes the metrics again: it reads no metrics.json
        code, lines = _command("run", manifest, "--out", out, "--resume", "--quiet")
    assert (code, lines) == (2, [f"agv-cosim: error: {run / name}: is {kind}, not a "
                                 "regular file"])
    assert (run / name).is_symlink() or (run / name).is_fifo()  # left as it was


def test_timings_that_are_a_fifo_are_refused_by_resume(results):
    manifest, out = results
    (out / "timings.csv").unlink()
    os.mkfifo(out / "timings.csv")
    code, lines = _command("run", manifest, "--out", out, "--resume", "--quiet")
    assert (code, lines) == (2, [f"agv-cosim: error: {out / 'timings.csv'}: is a FIFO, "
                                 "not a regular file"])


def test_a_record_larger_than_its_limit_is_refused(results):
    """A run.json beyond files.JSON_LIMIT (64 MiB) is refused by its size, unread (a
    sparse file: no disk used)."""
    _, out = results
    run_json = sorted(p for p in out.iterdir() if p.is_dir())[0] / "run.json"
    run_json.unlink()
    with open(run_json, "wb") as stream:
        stream.truncate(files.JSON_LIMIT + 1)
    code, lines = _command("report", out)
    assert (code, lines) == (2, [f"agv-cosim: error: {run_json}: is "
                                 f"{files.JSON_LIMIT + 1} bytes; at most "
                                 f"{files.JSON_LIMIT} are read"])


@pytest.mark.parametrize("key", ["manifest", "fmu"])
def test_the_report_does_not_open_a_fifo_named_by_run_json(results, tmp_path, key):
    """A manifest or FMU path in run.json that is now a FIFO is not read: the page is
    written (it says why the manifest was not used; the FMU gives no units)."""
    _, out = results
    fifo = tmp_path / ("fifo.toml" if key == "manifest" else "fifo.fmu")
    os.mkfifo(fifo)
    for run in (p for p in out.iterdir() if p.is_dir()):
        if key == "manifest":
            _edit_run_json(run / "run.json", manifest=str(fifo))
        else:
            _edit_run_json(run / "run.json", fmus={"gain": str(fifo)})
    code, lines = _command("report", out)
    assert (code, lines) == (0, [])
    page = (out / "index.html").read_text()
    if key == "manifest":
        assert f"{fifo}: is a FIFO, not a regular file; not used" in page


def test_a_fifo_in_an_ssp_package_folder_is_refused(tmp_path):
    package = tmp_path / "package.ssp"  # an unpacked package: a folder
    package.mkdir()
    os.mkfifo(package / "SystemStructure.ssd")
    code, lines = _command("validate", package)
    assert (code, lines) == (2, [f"agv-cosim: error: {package}: SystemStructure.ssd: is a "
                                 "FIFO, not a regular file"])


def test_fmu_hashing_refuses_a_fifo(tmp_path):
    """system.model.file_sha256 (the FMUs' and SSP packages' hashes) never opens a FIFO
    for reading (it blocked forever)."""
    fifo = tmp_path / "x.fmu"
    os.mkfifo(fifo)
    code = ("import sys\nfrom agv_cosim.system.model import file_sha256\n"
            "from agv_cosim.errors import UnreadableFile\n"
            "try:\n    file_sha256(sys.argv[1])\nexcept UnreadableFile as error:\n"
            "    print(error)\n")
    done = subprocess.run([sys.executable, "-c", code, str(fifo)], capture_output=True,
                          text=True, timeout=LIMIT)
    assert done.stdout.strip() == f"{fifo}: is a FIFO, not a regular file"


#: calls that open or read a file by its name, not through agv_cosim.files
_DIRECT = re.compile(r"(?<![\w.])open\(|\.read_text\(|\.read_bytes\(|json\.load\(|"
                     r"read_csv\((?!io\.StringIO|stream)|ElementTree\.parse\(|tomllib\.load\(|"
                     r"ZipFile\((?!stream)")


def test_the_reading_helper_is_used_everywhere():
    """No module of the report, --resume, the API, the manifest and SSP loaders or the
    time series opens a file by its name but through agv_cosim.files (the page's
    template, a file of the package, aside)."""
    root = Path(cli.__file__).parent
    modules = [*sorted((root / "report").glob("*.py")), root / "pipeline" / "resume.py",
               root / "api.py", root / "manifest" / "load.py", root / "ssp" / "importer.py",
               root / "timeseries.py"]
    found = []
    for module in modules:
        text = module.read_text()
        for match in _DIRECT.finditer(text):
            line = text[:match.start()].count("\n") + 1
            source = text.splitlines()[line - 1]
            if "#" in source[:source.find(match.group())] or \
                    "page_template.html" in text[max(0, match.start() - 80):match.start()]:
                continue
            found.append(f"{module.relative_to(root)}:{line}: {source.strip()}")
    assert found == []


# --------------------------------------------------------------------------- the API

def _rewrite(path, data):
    path.unlink()
    path.write_bytes(data if isinstance(data, bytes) else data.encode())


def _run_json(results, **changes):
    """run.json of the first run with ``changes`` (None: the key removed)."""
    _, out = results
    path = out / _first_run(out) / "run.json"
    record = json.loads(path.read_text())
    record.update(changes)
    _rewrite(path, json.dumps(record))


def _first_run(out):
    return sorted(p.name for p in out.iterdir() if p.is_dir())[0]


@pytest.mark.parametrize("damage, read, culprit", [
    (lambda out: _rewrite(out / "summary.csv", b"run,variant,status\nb\xe9se,,complete\n"),
     lambda r: r.runs, "summary.csv"),                                 # UnicodeDecodeError
    (lambda out: _rewrite(out / "summary.csv", "a,b\n1,2\n"),
     lambda r: r.summary, "summary.csv"),                              # KeyError 'run'
    (lambda out: _rewrite(out / "summary.csv", (out / "summary.csv").read_text()
                          + '"unclosed\n'),
     lambda r: r.summary, "summary.csv"),                              # ParserError
    (lambda out: _rewrite(out / _first_run(out) / "run.json", "[1, 2]"),
     lambda r: r.runs, "run.json"),                                    # AttributeError
    (lambda out: _rewrite(out / _first_run(out) / "run.json", '{"rows": "many"}'),
     lambda r: r.runs, "run.json"),                                    # ValueError
    (lambda out: _rewrite(out / _first_run(out) / "run.json", '{"sweep_point": [1]}'),
     lambda r: r.runs, "run.json"),                                    # TypeError
    (lambda out: _rewrite(out / _first_run(out) / "run.json", "{not json"),
     lambda r: r.runs, "run.json"),
    (lambda out: _rewrite(out / _first_run(out) / "timeseries.csv", "time,a\n0,1\n1,2,3\n"),
     lambda r: r.timeseries(r.runs[0].label), "timeseries.csv"),      # ParserError
    (lambda out: _rewrite(out / _first_run(out) / "timeseries.csv", "t,a\n0,1\n"),
     lambda r: r.timeseries(r.runs[0].label), "timeseries.csv"),      # ValueError (index)
    (lambda out: _rewrite(out / _first_run(out) / "timeseries.csv", b"time,a\n0,\xff\n"),
     lambda r: r.timeseries(r.runs[0].label), "timeseries.csv"),      # UnicodeDecodeError
])
def test_a_damaged_result_folder_raises_agv_cosim_error(results, damage, read, culprit):
    """open_results on a damaged folder raises AgvCosimError, one line naming the
    damaged file (before: UnicodeDecodeError, KeyError 'run', ParserError,
    AttributeError, ValueError, TypeError)."""
    _, out = results
    damage(out)
    with pytest.raises(agv_cosim.AgvCosimError) as raised:
        read(agv_cosim.open_results(out))
    text = str(raised.value)
    assert text.startswith(str(out)) and f"{culprit}: " in text and "\n" not in text


def test_units_of_a_damaged_run_json_are_unknown_not_an_exception(results):
    """run.json without ``units`` whose ``fmus`` and ``fmu_sha256`` are not tables
    (before: AttributeError): the units are unknown (None), the values are read."""
    _, out = results
    _run_json(results, units=None, fmus=["x"], fmu_sha256=3)
    label = _first_run(out)
    frame = agv_cosim.open_results(out).timeseries(label)
    units = frame.attrs["units"]
    assert len(frame) == 11 and units.pop("time") == "s" and set(units.values()) == {None}


@pytest.mark.parametrize("changes", [
    {"fmus": ["x"]}, {"fmus": "x", "fmu_sha256": ["y"]}, {"fmu_sha256": 3},
    {"fmus": {"gain": 7}}, {"fmus": {"gain": ["x"]}}, {"versions": ["x"]},
    {"versions": "1.0"}, {"manifest": 7}], ids=lambda c: json.dumps(c))
def test_the_page_of_a_damaged_run_json_is_written(results, changes):
    """run.json whose ``fmus``, ``fmu_sha256`` or ``versions`` are not tables of text, or
    whose ``manifest`` is not text (before: AttributeError, or TypeError sorting an FMU
    path 7 with the other run's text, or making a Path of 7): the page is written, the
    damaged value shown as text or not at all."""
    _, out = results
    _run_json(results, **changes)
    assert cli.main(["report", str(out)]) == 0
    page = (out / "index.html").read_text()
    assert _first_run(out) in page  # the damaged run is listed with the others
    if changes.get("fmus") == {"gain": 7}:
        assert "<code>7</code>" in page


def test_a_run_label_cannot_leave_the_folder(results, tmp_path):
    """A summary.csv that lists ``../outside/x`` is refused: a run label is one path
    component, the folder of a run listed in the folder's own summary.csv (before:
    timeseries() read ../outside/x/timeseries.csv)."""
    _, out = results
    outside = tmp_path / "outside" / "x"
    shutil.copytree(out / _first_run(out), outside)
    _rewrite(out / "summary.csv", "run,variant,status\n../outside/x,,complete\n")
    with pytest.raises(agv_cosim.AgvCosimError, match=r"summary.csv: row 2: run "
                       r"'\.\./outside/x' is not a plain folder name"):
        agv_cosim.open_results(out).timeseries("../outside/x")


def test_a_run_folder_that_is_a_link_is_refused(results, tmp_path):
    _, out = results
    label = _first_run(out)
    shutil.move(out / label, tmp_path / "elsewhere")
    (out / label).symlink_to(tmp_path / "elsewhere")
    with pytest.raises(agv_cosim.AgvCosimError, match="is a symbolic link"):
        agv_cosim.open_results(out).timeseries(label)


def test_a_timeseries_that_is_a_fifo_is_refused_by_the_api(results):
    _, out = results
    path = out / _first_run(out) / "timeseries.csv"
    path.unlink()
    os.mkfifo(path)
    code = ("import sys, agv_cosim\ntry:\n    r = agv_cosim.open_results(sys.argv[1])\n"
            "    r.timeseries(r.runs[0].label)\nexcept agv_cosim.AgvCosimError as error:\n"
            "    print(error)\n")
    done = subprocess.run([sys.executable, "-c", code, str(out)], capture_output=True,
                          text=True, timeout=LIMIT)
    assert done.stdout.strip() == f"{path}: is a FIFO, not a regular file"


@pytest.mark.parametrize("options, message", [
    ({"variants": [1]}, "variants: 1 is not a variant name (a string)"),
    ({"variants": 1}, "variants: 1 is not a list of strings"),
    ({"sets": [3]}, "sets: 3 is not an override 'component.parameter=value' (a string)"),
    ({"out": 5}, "out: 5 is not a path"),
])
def test_bad_options_raise_agv_cosim_error(chain, tmp_path, options, message):
    """Options of agv_cosim.run of the wrong type raise AgvCosimError naming the option
    (before: TypeError), and nothing is written."""
    options.setdefault("out", tmp_path / "out")
    with pytest.raises(agv_cosim.AgvCosimError) as raised:
        agv_cosim.run(chain(), quiet=True, **options)
    assert str(raised.value) == message
    assert not (tmp_path / "out").exists()


def test_a_manifest_that_is_not_a_path_raises_agv_cosim_error():
    with pytest.raises(agv_cosim.AgvCosimError, match="manifest: 5 is not a path"):
        agv_cosim.run(5, quiet=True)


def test_a_time_table_larger_than_its_limit_is_refused(chain, tmp_path):
    """A time table named by a manifest is read whole up to files.CSV_LIMIT (256 MiB);
    a larger one (sparse: no disk used) is refused by its size, unread."""
    table = tmp_path / "in.csv"
    with open(table, "wb") as stream:
        stream.truncate(files.CSV_LIMIT + 1)
    path = chain()
    path.write_text(path.read_text().replace(
        "[components.src]\n", f'[components.tab]\ntable = "{table}"\n[components.src]\n'))
    code, lines = _command("validate", path, "--no-init")
    number = path.read_text().splitlines().index(f'table = "{table}"') + 1
    assert (code, lines) == (2, [f"agv-cosim: error: {path}:{number}: components.tab.table: "
                                 f"'{table}' is {files.CSV_LIMIT + 1} bytes; at most "
                                 f"{files.CSV_LIMIT} are read"])
