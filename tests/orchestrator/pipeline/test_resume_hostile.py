"""``--resume`` against a hostile tester (issue 32): it touches only what the command
runs, it never deletes a user's file, it compares every input that changes a result
(table options, the bytes of the files parameters name), it checks a run's time series
whole; and a file a parameter names is read relative to the manifest, by the FMU and by
the metrics alike.
"""

import hashlib
import json
import os
import shutil
from pathlib import Path

import pytest

from agv_cosim import cli
from agv_cosim.build import build_one, default_components_dir
from agv_cosim.report.records import TIMINGS, read_timings

from result_folders import assert_same_folder, folder_contents

#: two variants of the chain (tests/orchestrator/conftest.py), one run each
TWO_VARIANTS = """
[variants.a.components.gain]
parameters = { k = 1.0 }
[variants.b.components.gain]
parameters = { k = 5.0 }
"""


def _run(path, out, *options):
    return cli.main(["run", str(path), "--out", str(out), "--jobs", "1", "--no-init",
                     *options])


def _files(folder):
    folder = Path(folder)
    return {str(p.relative_to(folder)): p.read_bytes()
            for p in sorted(folder.rglob("*")) if p.is_file()}


def _summary(folder):
    return (Path(folder) / "summary.csv").read_text().splitlines()


def test_resume_of_one_variant_keeps_the_other_variants_runs(chain, tmp_path, capsys):
    """``--variant b --resume`` after a change to b (and to a) reruns b and keeps a's
    run as it is: its files, byte for byte, its rows of summary.csv (in the manifest's
    order) and timings.csv; the page shows it."""
    path = chain(extra=TWO_VARIANTS, stop=0.3)
    out = tmp_path / "out"
    assert _run(path, out, "--quiet") == 0
    before = _files(out / "a")
    assert set(before) == {"timeseries.csv", "metrics.json", "run.json"}
    a_row = next(line for line in _summary(out) if line.startswith("a,"))
    a_timing = read_timings(out / TIMINGS)["a"]
    path.write_text(path.read_text().replace("k = 1.0", "k = 2.0")
                    .replace("k = 5.0", "k = 6.0"))
    capsys.readouterr()
    assert _run(path, out, "--variant", "b", "--resume") == 0
    err = capsys.readouterr().err
    assert (out / "a").is_dir() and _files(out / "a") == before
    assert "reused 0 of 1 run(s)" in err and "kept 1 run(s) of other variants" in err
    assert [line.split(",")[0] for line in _summary(out)] == ["run", "a", "b"]
    assert _summary(out)[1] == a_row
    assert read_timings(out / TIMINGS)["a"] == a_timing
    assert json.loads((out / "b" / "run.json").read_text())["parameters"]["gain"]["k"] == 6.0
    page = (out / "index.html").read_text()
    assert 'href="a/run.json"' in page and 'href="b/run.json"' in page

    # every variant run: a's changed inputs run it again, the folder is a clean run's
    assert _run(path, out, "--resume", "--quiet") == 0
    assert json.loads((out / "a" / "run.json").read_text())["parameters"]["gain"]["k"] == 2.0
    assert_same_folder(out, _clean(path, tmp_path / "clean"))


def _clean(path, out):
    assert _run(path, out, "--quiet") == 0
    return out


def test_resume_never_deletes_a_users_file(chain, tmp_path, capsys):
    """A file or folder this tool does not write, at the top of the result folder or in
    a run's folder (run again or not), is kept in the resumed folder, and said; the rest
    of the folder is a clean run's."""
    path = chain(extra='[sweep]\n"gain.k" = [1.0, 2.0, 4.0]\n', stop=0.3)
    out = tmp_path / "out"
    assert _run(path, out, "--quiet") == 0
    runs = sorted(p.parent.name for p in out.glob("*/run.json"))
    assert len(runs) == 3
    (out / "notes.txt").write_text("my notes\n")
    (out / "mine" / "deep").mkdir(parents=True)
    (out / "mine" / "deep" / "data.bin").write_bytes(b"\x00\x01")
    (out / "mine" / "deep").chmod(0o555)
    (out / "link").symlink_to("notes.txt")
    for run in runs:
        (out / run / "remark.txt").write_text(f"{run}\n")
    # run 0 is reused, run 1 is of a sweep point now gone, run 2 runs again (as if it
    # had not completed)
    path.write_text(path.read_text().replace("[1.0, 2.0, 4.0]", "[1.0, 3.0, 4.0]"))
    record = json.loads((out / runs[2] / "run.json").read_text())
    (out / runs[2] / "run.json").unlink()
    (out / runs[2] / "run.json").write_text(json.dumps({**record, "status": "partial"}))
    capsys.readouterr()
    assert _run(path, out, "--resume") == 0
    err = capsys.readouterr().err
    assert (out / "notes.txt").read_text() == "my notes\n"
    assert (out / "mine" / "deep" / "data.bin").read_bytes() == b"\x00\x01"
    assert (out / "mine" / "deep").stat().st_mode & 0o777 == 0o555
    (out / "mine" / "deep").chmod(0o755)
    assert os.readlink(out / "link") == "notes.txt"
    for run in runs:
        assert (out / run / "remark.txt").read_text() == f"{run}\n"
    assert "reused 1 of 3 run(s)" in err
    assert "kept 6 file(s) not written by agv-cosim: " in err
    assert f"{runs[0]}/remark.txt, " in err and "link, mine and 1 more" in err
    assert not (out / runs[1] / "run.json").exists()  # the stale run itself is gone
    clean = _clean(path, tmp_path / "clean")
    mine = folder_contents(out)
    users = {"notes.txt", "link", "mine/deep/data.bin",
             *(f"{run}/remark.txt" for run in runs)}
    assert users <= set(mine)
    for name in users:
        (out / name).unlink()
    (out / "mine" / "deep").rmdir()
    (out / "mine").rmdir()
    (out / runs[1]).rmdir()
    assert_same_folder(out, clean)


def test_a_run_replacing_its_folder_keeps_a_users_file(chain, tmp_path, capsys):
    """A run without --resume that replaces a result folder of ours (of this manifest or
    of another) keeps every file and folder it did not write, at the same place, and
    says so; what it wrote before is replaced by a clean run's folder."""
    path = chain(extra='[sweep]\n"gain.k" = [1.0, 2.0]\n', stop=0.3)
    out = tmp_path / "out"
    assert _run(path, out, "--quiet") == 0
    runs = sorted(p.parent.name for p in out.glob("*/run.json"))
    (out / "notes.txt").write_text("my notes\n")
    (out / "mine").mkdir()
    (out / "mine" / "data.bin").write_bytes(b"\x00\x01")
    (out / runs[0] / "remark.txt").write_text("kept\n")
    other = chain(stop=0.2, name="other.toml")  # another manifest's run into the same folder
    capsys.readouterr()
    assert _run(other, out) == 0
    err = capsys.readouterr().err
    assert "kept 3 file(s) not written by agv-cosim: " in err
    assert (out / "notes.txt").read_text() == "my notes\n"
    assert (out / "mine" / "data.bin").read_bytes() == b"\x00\x01"
    assert (out / runs[0] / "remark.txt").read_text() == "kept\n"
    assert not (out / runs[0] / "run.json").exists()  # the earlier run itself is gone
    (out / "notes.txt").unlink()
    shutil.rmtree(out / "mine")
    shutil.rmtree(out / runs[0])
    assert_same_folder(out, _clean(other, tmp_path / "clean"))


def test_resume_reruns_a_run_whose_timeseries_was_cut(chain, tmp_path, capsys):
    """A timeseries.csv cut in the middle of its last row (as many rows) is not reused:
    the run is run again and the folder is a clean run's."""
    path = chain(stop=0.3)
    out = tmp_path / "out"
    assert _run(path, out, "--quiet") == 0
    csv_file = out / "base" / "timeseries.csv"
    data = csv_file.read_bytes()
    rows = data.count(b"\n")
    cut = data[:-4]  # the last row's newline and its last digits
    assert cut.count(b"\n") == rows - 1 and not cut.endswith(b"\n")  # still `rows` rows
    csv_file.write_bytes(cut)
    capsys.readouterr()
    assert _run(path, out, "--resume") == 0
    assert "reused 0 of 1 run(s)" in capsys.readouterr().err
    assert csv_file.read_bytes() == data
    assert_same_folder(out, _clean(path, tmp_path / "clean"))
    # unchanged, it is reused: run.json records the hash it is checked against
    capsys.readouterr()
    assert _run(path, out, "--resume") == 0
    assert "reused 1 of 1 run(s)" in capsys.readouterr().err
    record = json.loads((out / "base" / "run.json").read_text())
    assert record["timeseries_sha256"] == hashlib.sha256(data).hexdigest()


#: a time table driving the gain: its interpolation changes the result
TABLE = """
name = "tab"
[simulation]
start = 0.0
stop = 1.0
step = 0.25
[components.tab]
table = "input.csv"
interpolation = {{ u = "linear" }}
[components.gain]
fmu = "{gain}"
[[connections]]
from = "tab.u"
to = "gain.u"
"""


def test_resume_reruns_a_run_whose_table_interpolation_changed(fmus, tmp_path, capsys):
    path = tmp_path / "tab.toml"
    path.write_text(TABLE.format(gain=fmus["agv_test_gain"]))
    (tmp_path / "input.csv").write_text("time,u\n0,0\n1,1\n")
    out = tmp_path / "out"
    assert _run(path, out, "--quiet") == 0
    linear = (out / "base" / "timeseries.csv").read_text()
    path.write_text(path.read_text().replace('"linear"', '"hold"'))
    capsys.readouterr()
    assert _run(path, out, "--resume") == 0
    assert "reused 0 of 1 run(s)" in capsys.readouterr().err
    hold = (out / "base" / "timeseries.csv").read_text()
    assert hold != linear
    inputs = json.loads((out / "base" / "run.json").read_text())["inputs"]
    assert inputs["tables"] == {"tab": {"interpolation": {"u": "hold"}}}
    assert_same_folder(out, _clean(path, tmp_path / "clean"))


@pytest.fixture(scope="module")
def sensor_fmu(tmp_path_factory):
    """The vision sensor FMU alone (a few seconds)."""
    script = default_components_dir() / "agv_core" / "sensors" / "agv_vision_sensor.py"
    return build_one(script, tmp_path_factory.mktemp("sensor")).fmu


#: the sensor measuring a point moving along y = 0 against a waypoint path
WAYPOINTS = """
name = "wp"
[simulation]
start = 0.0
stop = 1.0
step = 0.1
[components.pose]
table = "pose.csv"
units = {{ x = "m", y = "m", heading = "rad" }}
[components.sensor]
fmu = "{sensor}"
parameters = {{ path = "waypoints:file=wp.csv", frame_period = 0.0, latency = 0.0, \
noise_lateral = 0.0, noise_heading = 0.0 }}
[[connections]]
from = "pose.x"
to = "sensor.x"
[[connections]]
from = "pose.y"
to = "sensor.y"
[[connections]]
from = "pose.heading"
to = "sensor.heading"
[metrics]
lateral_error = "sensor.lateral_error"
reference = {{ path = "waypoints:file=wp.csv", x = "pose.x", y = "pose.y" }}
"""


@pytest.fixture
def waypoints(sensor_fmu, tmp_path):
    """The manifest in its own folder, with wp.csv (the line y = 0) beside it."""
    folder = tmp_path / "m"
    folder.mkdir()
    path = folder / "wp.toml"
    path.write_text(WAYPOINTS.format(sensor=sensor_fmu))
    (folder / "pose.csv").write_text("time,x,y,heading\n0,0,0,0\n1,1,0,0\n")
    (folder / "wp.csv").write_text("x,y\n-1,0\n10,0\n")
    return path


def _metrics(out):
    return json.loads((Path(out) / "base" / "metrics.json").read_text())


@pytest.mark.slow  # builds the sensor FMU, runs it in processes
def test_a_waypoint_file_is_the_manifests_wherever_the_run_starts(waypoints, tmp_path,
                                                                   monkeypatch, capsys):
    """Started in a folder holding another wp.csv (the line y = 5), or none, the FMU and
    the metrics read the wp.csv beside the manifest: lateral error 0; run.json is the
    same bytes from either folder and records the file by its name and SHA-256."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "wp.csv").write_text("x,y\n-1,5\n10,5\n")
    empty = tmp_path / "empty" / "deeper"
    empty.mkdir(parents=True)
    records = []
    for cwd, manifest in ((elsewhere, "../m/wp.toml"), (empty, "../../m/wp.toml")):
        monkeypatch.chdir(cwd)
        out = tmp_path / f"out-{cwd.name}"
        assert _run(manifest, out, "--quiet") == 0, capsys.readouterr().err
        values = _metrics(out)
        assert values["lateral_error_max"] == pytest.approx(0.0, abs=1e-9), values
        assert values["path_error_max"] == pytest.approx(0.0, abs=1e-9), values
        records.append((out / "base" / "run.json").read_bytes())
    assert records[0] == records[1]
    record = json.loads(records[0])
    assert record["parameters"]["sensor"]["path"] == "waypoints:file=wp.csv"
    assert record["manifest"] == str(waypoints)
    digest = hashlib.sha256((waypoints.parent / "wp.csv").read_bytes()).hexdigest()
    assert record["inputs"]["files"] == {"sensor.path": {"wp.csv": digest}}

    # a file that is not beside the manifest (but in the current folder): one line
    # naming the parameter, no run
    waypoints.write_text(waypoints.read_text().replace(
        'path = "waypoints:file=wp.csv", frame', 'path = "waypoints:file=here.csv", frame'))
    shutil.copyfile(elsewhere / "wp.csv", empty / "here.csv")
    capsys.readouterr()
    assert _run(waypoints, tmp_path / "missing", "--quiet") == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"agv-cosim: error: {waypoints}:") and "\n" not in err
    assert "components.sensor.parameters.path: 'sensor.path': file 'here.csv' (relative " \
           f"to the manifest): {waypoints.parent / 'here.csv'}: No such file" in err
    assert not (tmp_path / "missing").exists()


@pytest.mark.slow  # builds the sensor FMU, runs it in processes
def test_resume_reruns_a_run_whose_waypoint_file_changed(waypoints, tmp_path, capsys):
    out = tmp_path / "out"
    assert _run(waypoints, out, "--quiet") == 0
    assert _metrics(out)["lateral_error_max"] == pytest.approx(0.0, abs=1e-9)
    (waypoints.parent / "wp.csv").write_text("x,y\n-1,0.5\n10,0.5\n")
    capsys.readouterr()
    assert _run(waypoints, out, "--resume") == 0
    assert "reused 0 of 1 run(s)" in capsys.readouterr().err
    values = _metrics(out)
    assert values["lateral_error_max"] == pytest.approx(0.5, abs=1e-9)
    assert values["lateral_error_max"] == pytest.approx(values["path_error_max"], abs=1e-9)
    assert_same_folder(out, _clean(waypoints, tmp_path / "clean"))
    shutil.rmtree(tmp_path / "clean")


def test_resume_refuses_a_users_link_where_a_run_is_written(chain, tmp_path, capsys):
    """A link (or file) of the user's named as a run that runs again is neither deleted
    nor written through: one line naming it, the folder left as it was."""
    path = chain(stop=0.3)
    out = tmp_path / "out"
    assert _run(path, out, "--quiet") == 0
    mine = tmp_path / "mine"
    mine.mkdir()
    shutil.rmtree(out / "base")
    (out / "base").symlink_to(mine)
    before = _files(out)
    capsys.readouterr()
    assert _run(path, out, "--resume", "--quiet") == 2
    assert capsys.readouterr().err.strip() == (
        f"agv-cosim: error: {out / 'base'}: not a run folder of agv-cosim, where run "
        "'base' is written; refusing to resume (move it away)")
    assert os.readlink(out / "base") == str(mine) and not any(mine.iterdir())
    assert _files(out) == before


def test_a_file_a_parameter_names_is_checked_without_blocking(tmp_path):
    """What the check of a run says of a file a parameter names: missing, a folder, a
    FIFO (refused at once, not read) or a link to a device; a regular file (or a link to
    one) is fine and hashed by the name as written."""
    from agv_cosim.system.files import file_problem, hash_files, named_files, resolved

    os.mkfifo(tmp_path / "fifo.csv")
    (tmp_path / "dir.csv").mkdir()
    (tmp_path / "zero.csv").symlink_to("/dev/zero")
    (tmp_path / "wp.csv").write_text("x,y\n0,0\n1,0\n")
    (tmp_path / "link.csv").symlink_to("wp.csv")
    for name, why in (("missing.csv", "No such file"), ("dir.csv", "not a regular file"),
                      ("fifo.csv", "not a regular file"), ("zero.csv", "not a regular file")):
        problem = file_problem(f"waypoints:file={name}", tmp_path)
        assert problem == (f"file '{name}' (relative to the manifest): {tmp_path / name}: "
                           f"{why}" + (" or directory" if why == "No such file" else ""))
    assert file_problem("waypoints:file=link.csv", tmp_path) is None
    assert file_problem("line:x0=1", tmp_path) is None and named_files(2.0) == []
    assert resolved("waypoints:file=wp.csv", tmp_path) == f"waypoints:file={tmp_path}/wp.csv"
    digest = hashlib.sha256(b"x,y\n0,0\n1,0\n").hexdigest()
    assert hash_files({"s.path": "waypoints:file=link.csv", "s.k": 1.0}, tmp_path) == {
        "s.path": {"link.csv": digest}}
    assert "cannot be written in a path string" in file_problem(
        "waypoints:file=wp.csv", tmp_path / "a,b")


# ---------------------------------------------------------------- a run's output.txt

#: the rogue test FMU (tests/fmu_src/agv_test_rogue.py) printing a few bytes a step
#: (to fds 1 and 2, and a line with print): its run has an output.txt
PRINTING = """
name = "printing"
[simulation]
stop = 0.05
step = 0.01
[components.r]
fmu = "{fmu}"
parameters = {{ stdout_bytes = {bytes} }}
"""


def _printing(fmus, tmp_path, stdout_bytes=12):
    path = tmp_path / "printing.toml"
    path.write_text(PRINTING.format(fmu=fmus["agv_test_rogue"], bytes=stdout_bytes))
    return path


def _cut(path):
    data = path.read_bytes()
    path.unlink()
    path.write_bytes(data[:-5])


def _replaced(path):
    data = path.read_bytes()
    path.unlink()
    path.write_bytes(data[:10] + bytes([data[10] ^ 1]) + data[11:])  # as many bytes


def _deleted(path):
    path.unlink()


def _linked(path):
    """A link to a file of the same bytes, outside the result folder."""
    twin = path.parent.parent.parent / "twin.txt"
    shutil.copyfile(path, twin)
    path.unlink()
    path.symlink_to(twin)


def _fifo(path):
    path.unlink()
    os.mkfifo(path)  # read, it would block the resume forever


def _huge(path):
    path.unlink()
    with open(path, "wb") as stream:  # 1 TiB, sparse: reading it would take hours
        stream.truncate(1 << 40)


@pytest.mark.parametrize("change", [_cut, _replaced, _deleted, _linked, _fifo, _huge])
def test_resume_reruns_a_run_whose_output_is_not_the_one_it_printed(fmus, tmp_path, capsys,
                                                                    change):
    """run.json records the SHA-256 and size of the run's output.txt; an output.txt cut,
    changed (as many bytes), deleted, a link (to the same bytes), a FIFO or a huge file
    (neither opened nor read) reruns the run, as a changed timeseries.csv does: the
    resumed folder is a clean run's, its output.txt the one the run printed."""
    path = _printing(fmus, tmp_path)
    out = tmp_path / "out"
    assert _run(path, out, "--quiet") == 0
    output = out / "base" / "output.txt"
    printed = output.read_bytes()
    assert b"FMU output" in printed and b"a line printed by the FMU" in printed
    record = json.loads((out / "base" / "run.json").read_text())
    assert record["output_sha256"] == hashlib.sha256(printed).hexdigest()
    assert record["output_bytes"] == len(printed)
    change(output)
    capsys.readouterr()
    assert _run(path, out, "--resume") == 0
    assert "reused 0 of 1 run(s)" in capsys.readouterr().err
    assert output.read_bytes() == printed and not output.is_symlink()
    assert_same_folder(out, _clean(path, tmp_path / "clean"))


def test_resume_keeps_a_run_whose_output_is_intact(fmus, tmp_path, capsys):
    """An output.txt as the run left it is kept (hard-linked) with the run, and the
    resumed run's run.json records it as a clean run's does."""
    path = _printing(fmus, tmp_path)
    out = tmp_path / "out"
    assert _run(path, out, "--quiet") == 0
    inode = (out / "base" / "output.txt").stat().st_ino
    capsys.readouterr()
    assert _run(path, out, "--resume") == 0
    assert "reused 1 of 1 run(s)" in capsys.readouterr().err
    assert (out / "base" / "output.txt").stat().st_ino == inode
    assert "output_sha256" in json.loads((out / "base" / "run.json").read_text())
    assert_same_folder(out, _clean(path, tmp_path / "clean"))


def _without_output_keys(run_json):
    """run.json as an agv-cosim before output_sha256 wrote it."""
    record = json.loads(run_json.read_text())
    record.pop("output_sha256", None)
    record.pop("output_bytes", None)
    run_json.unlink()
    run_json.write_text(json.dumps(record, indent=1, sort_keys=True) + "\n")


def test_resume_of_an_earlier_run_json_without_output_hash(fmus, tmp_path, capsys):
    """A run written by an earlier agv-cosim (run.json without ``output_sha256``): with
    an output.txt, nothing vouches for it and the run is run again; without one (a run
    that printed nothing, with ``output_sha256`` absent as it is now), it is reused."""
    path = _printing(fmus, tmp_path)
    out = tmp_path / "out"
    assert _run(path, out, "--quiet") == 0
    _without_output_keys(out / "base" / "run.json")
    capsys.readouterr()
    assert _run(path, out, "--resume") == 0
    assert "reused 0 of 1 run(s)" in capsys.readouterr().err
    assert_same_folder(out, _clean(path, tmp_path / "clean"))

    quiet = _printing(fmus, tmp_path, stdout_bytes=0)
    out = tmp_path / "quiet"
    assert _run(quiet, out, "--quiet") == 0
    assert not (out / "base" / "output.txt").exists()
    assert "output_sha256" not in json.loads((out / "base" / "run.json").read_text())
    _without_output_keys(out / "base" / "run.json")
    capsys.readouterr()
    assert _run(quiet, out, "--resume") == 0
    assert "reused 1 of 1 run(s)" in capsys.readouterr().err
    (out / "base" / "output.txt").write_text("put there by hand\n")
    capsys.readouterr()
    assert _run(quiet, out, "--resume") == 0
    assert "reused 0 of 1 run(s)" in capsys.readouterr().err
    assert not (out / "base" / "output.txt").exists()


@pytest.mark.slow  # starts a Dask cluster
def test_a_dask_run_records_its_output_as_a_local_run_does(cluster, fmus, tmp_path, capsys):
    """On Dask (a run host's worker prints), run.json records the output.txt that comes
    back, as a local run's does: what the FMU printed, its hash and size; --resume with
    Dask keeps the run. (The bytes need not equal a local run's: how the FMU's C-level
    and Python-level writes interleave depends on how the process's stdout is buffered,
    which differs between a local worker and a Dask run host.)"""
    path = _printing(fmus, tmp_path)
    remote = tmp_path / "remote"
    assert _run(path, remote, "--quiet", "--dask", cluster) == 0
    printed = (remote / "base" / "output.txt").read_bytes()
    assert b"FMU output" in printed
    for t in ("0.0", "0.01", "0.02", "0.03", "0.04"):
        assert f"a line printed by the FMU at t = {t}\n".encode() in printed
    keys = ("output_sha256", "output_bytes")
    record = json.loads((remote / "base" / "run.json").read_text())
    assert [record[k] for k in keys] == [hashlib.sha256(printed).hexdigest(), len(printed)]
    capsys.readouterr()
    assert _run(path, remote, "--resume", "--dask", cluster) == 0
    assert "reused 1 of 1 run(s)" in capsys.readouterr().err
