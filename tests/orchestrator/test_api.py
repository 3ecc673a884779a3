"""The Python API (agv_cosim.api): results as DataFrames, one exception type with the
command's message, and calls from a script without a ``__main__`` guard, from
``python -c``, from stdin and from a Jupyter kernel."""

import json
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import agv_cosim
from agv_cosim import cli
from agv_cosim.timeseries import read_timeseries

from manifests import localise

EXPERIMENTS = Path(__file__).resolve().parents[2] / "experiments"


def _python(*args, stdin=None, cwd=None, timeout=300):
    return subprocess.run([sys.executable, *args], input=stdin, capture_output=True,
                          text=True, cwd=cwd, timeout=timeout)


#: a script with no ``if __name__ == "__main__":`` guard; {call} is run or run_manifest
SCRIPT = """
import agv_cosim
{call}
"""
API_CALL = """results = agv_cosim.run({manifest!r}, out={out!r}, jobs=2, quiet=True)
print(results.summary[["run", "status"]].to_string(index=False))
print("complete" if results.complete else "NOT COMPLETE")"""
MANIFEST_CALL = """target, results, warnings = agv_cosim.run_manifest({manifest!r}, {out!r},
                                                    workers=2, quiet=True)
for result in results:
    print(result["label"], result["status"], result["error"])"""


def _sweep(chain):
    return chain(extra='[sweep]\n"gain.k" = [1.0, 2.0, 3.0]\n')


@pytest.mark.parametrize("call, how", [("run", "file"), ("run", "-c"), ("run", "stdin"),
                                       ("run_manifest", "file")])
def test_no_main_guard(chain, tmp_path, how, call):
    """The workers do not import the caller's main module: a script that calls the API at
    its top level (no guard) runs its runs once, each complete."""
    manifest, out = _sweep(chain), tmp_path / "out"
    code = SCRIPT.format(call=(API_CALL if call == "run" else MANIFEST_CALL).format(
        manifest=str(manifest), out=str(out)))
    if how == "file":
        script = tmp_path / "script.py"
        script.write_text(code)
        done = _python(str(script), cwd=tmp_path)
    elif how == "-c":
        done = _python("-c", code, cwd=tmp_path)
    else:
        done = _python("-", stdin=code, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert sum(" complete" in line for line in lines) == 3, done.stdout + done.stderr
    assert "died" not in done.stdout + done.stderr
    if call == "run":
        assert lines[-1] == "complete"
    summary = (out / "summary.csv").read_text().splitlines()
    assert len(summary) == 4 and all(",complete," in row for row in summary[1:])


def test_python_m_module(chain, tmp_path):
    """``python -m module``, whose main module multiprocessing would import by name."""
    manifest, out = _sweep(chain), tmp_path / "out"
    (tmp_path / "noguard.py").write_text(SCRIPT.format(call=API_CALL.format(
        manifest=str(manifest), out=str(out))))
    done = _python("-m", "noguard", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines()[-1] == "complete"


def test_results(chain, tmp_path):
    manifest = _sweep(chain)
    results = agv_cosim.run(manifest, out=tmp_path / "out", quiet=True)
    assert results.complete and not results.partial
    assert results.folder == tmp_path / "out"
    assert [r.status for r in results.runs] == ["complete"] * 3
    assert [r.point for r in results.runs] == [{"gain.k": k} for k in (1.0, 2.0, 3.0)]
    summary = results.summary
    assert list(summary["run"]) == [r.label for r in results.runs]
    assert list(summary["status"]) == ["complete"] * 3
    assert list(summary["gain.k"]) == [1.0, 2.0, 3.0]
    assert summary["message"].isna().all()
    label = results.runs[1].label
    frame = results.timeseries(label)
    times, columns = read_timeseries(tmp_path / "out" / label / "timeseries.csv")
    assert frame.index.name == "time" and list(frame.columns) == list(columns)
    assert frame.index.to_numpy().tobytes() == times.tobytes()  # bit-identical
    for name, values in columns.items():
        assert frame[name].to_numpy(dtype=values.dtype).tobytes() == values.tobytes(), name
    units = frame.attrs["units"]
    assert units["time"] == "s" and units["src.t_out"] == "s" and units["src.y"] == "1"
    assert units["src.count"] is None
    assert set(units) == {"time", *columns}
    with pytest.raises(agv_cosim.AgvCosimError, match="no run 'nope'"):
        results.timeseries("nope")


def test_summary_units_descriptions_and_message(chain, tmp_path):
    """summary.attrs: every column's unit and description (a metric's from
    docs/metrics.md); ``message`` is the one column the API adds to summary.csv's, as
    docs/api.md says."""
    from agv_cosim.report.metrics import METRICS

    manifest = chain(extra='[sweep]\n"gain.k" = [1.0, 2.0]\n[metrics]\nlateral_error = '
                           '"int.y"\ncontrol = "gain.y"\n')
    results = agv_cosim.run(manifest, out=tmp_path / "out", quiet=True)
    summary = results.summary
    header = (tmp_path / "out" / "summary.csv").read_text().splitlines()[0].split(",")
    assert list(summary.columns) == header + ["message"] and "message" not in header
    doc = (EXPERIMENTS.parent / "docs" / "api.md").read_text()
    row = next(line for line in doc.splitlines() if line.startswith("| `summary` |"))
    assert "Added from each run's `run.json` (not in the file): `message`" in row
    units, descriptions = summary.attrs["units"], summary.attrs["descriptions"]
    assert set(units) == set(descriptions) == set(summary.columns)
    assert units["lateral_error_max"] == "1"  # int.y's unit
    assert units["lateral_error_settling_time"] == "s"
    assert units["control_effort"] == "(1)^2 s" and units["run"] is None
    for name in summary.columns:
        if name in METRICS:
            assert descriptions[name].startswith(METRICS[name].definition), name
    assert "not complete" in descriptions["message"]
    assert "gain.k" in descriptions["gain.k"]


def test_open_results(chain, tmp_path):
    """A folder written by the command reads back the same; a run.json without units
    (an older agv-cosim) takes them from its FMUs."""
    manifest, out = _sweep(chain), tmp_path / "out"
    assert cli.main(["run", str(manifest), "--out", str(out), "--quiet"]) == 0
    results = agv_cosim.open_results(out)
    assert results.complete and len(results.runs) == 3
    label = results.runs[0].label
    units = results.timeseries(label).attrs["units"]
    info_path = out / label / "run.json"
    info = json.loads(info_path.read_text())
    assert info["units"] == units
    del info["units"]
    info_path.write_text(json.dumps(info))
    assert agv_cosim.open_results(out).timeseries(label).attrs["units"] == units
    with pytest.raises(agv_cosim.AgvCosimError, match="not a result folder"):
        agv_cosim.open_results(tmp_path)


def test_sets_and_check(chain, tmp_path, fmus):
    manifest = chain()
    results = agv_cosim.run(manifest, out=tmp_path / "a", quiet=True, sets={"gain.k": 5.0})
    assert json.loads((results.runs[0].folder / "run.json").read_text())[
        "parameters"]["gain"]["k"] == 5.0
    # a run that fails: its process dies (the crash FMU) -> failed with its reason
    crashing = chain(extra=f'[components.boom]\nfmu = "{fmus["agv_test_crash"]}"\n'
                           "parameters = { crash_time = 0.5 }\n", name="crash.toml")
    results = agv_cosim.run(crashing, out=tmp_path / "b", quiet=True)
    assert not results.complete
    [one] = results.runs
    assert one.status == "partial" and "signal" in one.message
    assert results.summary["message"][0] == one.message
    with pytest.raises(agv_cosim.AgvCosimError) as raised:
        agv_cosim.run(crashing, out=tmp_path / "b", quiet=True, check=True)
    assert str(raised.value).startswith(f"run {one.label} partial: ")
    assert raised.value.exit_code == 1


class _Bomb:
    """Unpickled (in the worker, with its job), it prints a line and ends the process."""

    def __reduce__(self):
        return (exec, ("import os, sys\nprint('the bomb went off', file=sys.stderr, "
                       "flush=True)\nos._exit(3)",))


def test_process_dies_before_the_run(chain, tmp_path):
    """A worker that dies before it starts its run: the run is failed with what its
    process said last, and the results show it (not a normal complete return)."""
    from agv_cosim.pipeline import execute, prepare

    manifest, jobs, _ = prepare(chain())
    jobs[0].bomb = _Bomb()  # travels with the job to the worker
    _, [result] = execute(manifest, jobs, tmp_path / "out", quiet=True)
    expected = ("the run's process died (exit code 3) before the run started; its last "
                "output: the bomb went off")
    assert (result["status"], result["error"]) == ("failed", expected)
    results = agv_cosim.open_results(tmp_path / "out")
    assert not results.complete
    assert [(r.status, r.message) for r in results.runs] == [("failed", expected)]


def _cli_error(capsys, argv):
    code = cli.main(argv)
    lines = capsys.readouterr().err.strip().splitlines()
    errors = [line.removeprefix("agv-cosim: error: ") for line in lines
              if line.startswith("agv-cosim: error: ")]
    assert errors, lines
    return code, errors


@pytest.mark.parametrize("old, new", [
    ("k = 3.0", "k = 3.0, kk = 1.0"),                                # unknown parameter
    ('from = "src.y"\nto = "gain.u"', 'from = "src.zz"\nto = "gain.u"'),  # unknown variable
    ("AgvTestGain.fmu", "Missing.fmu"),                              # missing FMU
    ("[simulation]", "[simulaton]"),                                 # bad section
    ("step = 0.1", "stp = 0.1"),                                     # bad key
])
def test_errors_are_the_commands(chain, tmp_path, capsys, old, new):
    path = chain()
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))
    code, lines = _cli_error(capsys, ["run", str(path), "--out", str(tmp_path / "c")])
    with pytest.raises(agv_cosim.AgvCosimError) as raised:
        agv_cosim.run(path, out=tmp_path / "a", quiet=True)
    assert str(raised.value) == lines[0]
    assert raised.value.lines == lines and raised.value.exit_code == code == 2
    assert not (tmp_path / "a").exists()


def test_error_foreign_out_folder(chain, tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("a user's file\n")
    code, lines = _cli_error(capsys, ["run", str(chain()), "--out", str(out)])
    with pytest.raises(agv_cosim.AgvCosimError) as raised:
        agv_cosim.run(chain(), out=out, quiet=True)
    assert [str(raised.value)] == lines and code == 2
    assert (out / "notes.txt").read_text() == "a user's file\n"


def test_bad_options(chain):
    with pytest.raises(agv_cosim.AgvCosimError, match="jobs: must be an integer >= 1"):
        agv_cosim.run(chain(), jobs=0)
    with pytest.raises(agv_cosim.AgvCosimError, match="timeout: "):
        agv_cosim.run(chain(), timeout=float("nan"))


def test_command_does_not_import_pandas(chain, tmp_path):
    code = textwrap.dedent(f"""
        import sys
        from agv_cosim import cli
        assert cli.main(["run", {str(chain())!r}, "--out", {str(tmp_path / "o")!r},
                         "--quiet"]) == 0
        print("pandas" in sys.modules)
    """)
    done = _python("-c", code)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "False"


NOTEBOOK_CELLS = [
    "import agv_cosim",
    "results = agv_cosim.run({manifest!r}, out={out!r})\nresults",
    "print(results.summary[['run', 'status']].to_string(index=False))",
    "from agv_cosim.pipeline.run import progress_bar\nprint(progress_bar().__module__)",
    # the bar as execute makes it, drawn at once
    "import sys\nbar = progress_bar()(total=10, desc='sweep', unit='step', delay=0.0, "
    "file=sys.stderr, mininterval=0.5, postfix={{'runs': '0/1'}})\n"
    "bar.update(10)\nbar.set_postfix(runs='1/1')\nbar.close()",
]


@pytest.mark.slow  # a kernel's start (about 10 s)
def test_jupyter_kernel(chain, tmp_path):
    """A notebook that calls agv_cosim.run, executed in an IPython kernel (nbclient):
    every run complete, the results shown as a table, the progress bar class the
    notebook's (tqdm.notebook with ipywidgets, else the text bar on stderr)."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    manifest, out = _sweep(chain), tmp_path / "out"
    cells = [nbformat.v4.new_code_cell(source.format(manifest=str(manifest), out=str(out)))
             for source in NOTEBOOK_CELLS]
    notebook = nbformat.v4.new_notebook(cells=cells)
    nbclient.NotebookClient(notebook, timeout=300, kernel_name="python3",
                            resources={"metadata": {"path": str(tmp_path)}}).execute()
    outputs = [cell.outputs for cell in notebook.cells]
    shown = outputs[1][-1]
    assert shown["output_type"] == "execute_result"
    assert "3/3 run(s) complete" in shown["data"]["text/plain"]
    assert "<table" in shown["data"]["text/html"]
    text = "".join(o.get("text", "") for o in outputs[2])
    assert text.count("complete") == 3, outputs
    errors = [o for cell in outputs for o in cell if o["output_type"] == "error"]
    assert not errors
    module = "".join(o.get("text", "") for o in outputs[3]).strip()
    assert module == ("tqdm.notebook" if _has("ipywidgets") else "agv_cosim.pipeline.run")
    drawn = outputs[4]
    if _has("ipywidgets"):  # a widget the notebook renders
        assert any("application/vnd.jupyter.widget-view+json" in o.get("data", {})
                   for o in drawn), drawn
    else:  # the text bar on the cell's stderr
        assert "10/10" in "".join(o.get("text", "") for o in drawn), drawn


def _has(name):
    import importlib.util

    return importlib.util.find_spec(name) is not None


DOC = Path(__file__).resolve().parents[2] / "docs" / "api.md"
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:e[-+]?\d+)?")


def _block(text, language):
    """The first fenced code block of ``language`` in ``text``."""
    found = re.search(rf"^```{language}\n(.*?)^```$", text, flags=re.M | re.S)
    assert found, f"no ```{language} block"
    return found.group(1)


def _shape(line):
    """A line with its numbers taken out: (the text around them, the numbers)."""
    return NUMBER.sub("#", line), [float(n) for n in NUMBER.findall(line)]


def test_doc_example(component_fmus, tmp_path):
    """docs/api.md's example, run on the shipped manifest (its FMUs the session's),
    prints what the page shows: the same lines, the same text, the same numbers to the
    digits shown."""
    text = DOC.read_text()
    code, shown = _block(text, "python"), _block(text, "text")
    manifest = re.search(r'agv_cosim\.run\("(experiments/[\w.]+\.toml)"', code).group(1)
    (tmp_path / "experiments").mkdir()
    localise(EXPERIMENTS / Path(manifest).name, tmp_path / "experiments", component_fmus)
    done = _python("-c", code, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    printed, expected = done.stdout.splitlines(), shown.splitlines()
    assert len(printed) == len(expected), done.stdout
    for got, want in zip(printed, expected):
        (got_text, got_numbers), (want_text, want_numbers) = _shape(got), _shape(want)
        assert got_text == want_text, (got, want)
        assert got_numbers == pytest.approx(want_numbers, rel=1e-5, abs=1e-12), (got, want)


@pytest.mark.parametrize("kernel, widgets, expected", [
    (False, True, "agv_cosim.pipeline.run"),   # a terminal: the text bar
    (True, False, "agv_cosim.pipeline.run"),   # a kernel without ipywidgets: the text bar
    (True, True, "tqdm.notebook"),             # a kernel with ipywidgets: the widget
])
def test_progress_bar_choice(monkeypatch, kernel, widgets, expected):
    import importlib.util
    import types

    from agv_cosim.pipeline.run import progress_bar

    shell = types.SimpleNamespace(config={"IPKernelApp": {}} if kernel else {})
    monkeypatch.setitem(sys.modules, "IPython",
                        types.SimpleNamespace(get_ipython=lambda: shell))
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *args: (
        (find_spec(name, *args) if widgets else None) if name == "ipywidgets"
        else find_spec(name, *args)))
    assert progress_bar().__module__ == expected


def test_summary_types(tmp_path):
    """summary.csv's numbers read back as floats (also "nan" and "inf", as written for
    non-finite metrics), text as text (a variant named "NA" stays "NA"), an empty cell
    as missing."""
    (tmp_path / "summary.csv").write_text(
        "run,variant,status,vehicle.reference_point,max_error,k\n"
        "a,NA,complete,rear,nan,1\nb,,failed,front,inf,2\nc,x,complete,rear,0.1,3\n")
    summary = agv_cosim.open_results(tmp_path).summary
    assert list(summary["variant"][[0, 2]]) == ["NA", "x"] and summary["variant"].isna()[1]
    assert list(summary["vehicle.reference_point"]) == ["rear", "front", "rear"]
    assert summary["max_error"].dtype == float
    assert summary["max_error"][0] != summary["max_error"][0]  # nan
    assert list(summary["max_error"][1:]) == [float("inf"), 0.1]
    assert list(summary["k"]) == [1, 2, 3]
    # no run.json (a run that never started): its status is the message
    assert list(summary["message"].isna()) == [True, False, True]
    assert summary["message"][1] == "failed"
