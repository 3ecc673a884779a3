"""What the start of a command imports: each process imports what it uses only.

Checked in a fresh interpreter each (``sys.modules`` after the work): ``agv-cosim
--help`` and ``agv-cosim list`` import neither the scientific stack nor the manifest's
schema; the fork server's preload and everything a run's worker starts with (it is
forked from the command, which has imported the pipeline) import no plotting and no
scipy; a figure is what imports matplotlib. How fast that makes them is measured by
benchmarks/bench_startup.py, not here.
"""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
HEAVY = ("matplotlib", "scipy", "scipy.signal", "pandas")


def _modules_after(code: str) -> set[str]:
    """The names in ``sys.modules`` after running ``code`` in a fresh interpreter."""
    script = code + "\nimport json, sys\nprint('MODULES=' + json.dumps(sorted(sys.modules)))\n"
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=120, cwd=ROOT)
    assert done.returncode == 0, done.stderr
    line = [x for x in done.stdout.splitlines() if x.startswith("MODULES=")][-1]
    return set(json.loads(line.removeprefix("MODULES=")))


def test_help_imports_no_science_and_no_schema():
    modules = _modules_after(
        "import contextlib, io\n"
        "from agv_cosim.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()) as out:\n"
        "    try:\n"
        "        main(['--help'])\n"
        "    except SystemExit:\n"
        "        pass\n"
        "assert 'export-ssp' in out.getvalue() and 'validate' in out.getvalue()\n")
    assert not modules & {*HEAVY, "numpy", "pydantic", "agv_cosim.manifest"}


@pytest.mark.skipif(not (ROOT / "fmus" / "AgvVehicle.fmu").is_file(),
                    reason="needs the built FMUs (make fmus)")
def test_list_imports_no_plotting_no_scipy_and_no_schema():
    modules = _modules_after(
        "import contextlib, io\n"
        "from agv_cosim.cli import main\n"
        "with contextlib.redirect_stdout(io.StringIO()) as out:\n"
        "    assert main(['list', 'fmus/AgvVehicle.fmu']) == 0\n"
        "assert 'wheelbase' in out.getvalue()\n")
    assert not modules & {*HEAVY, "pydantic", "agv_cosim.manifest"}


def test_examples_imports_no_fmu_tooling():
    # agv-cosim examples needs agv_cosim.build.examples only: the package's FMU build
    # names (agv_cosim.build.fmus, pythonfmu, fmpy) load on first use
    modules = _modules_after("from agv_cosim.build.examples import copy_examples\n")
    assert "agv_cosim.build.examples" in modules
    assert not modules & {"agv_cosim.build.fmus", "pythonfmu", "fmpy", *HEAVY}
    modules = _modules_after("from agv_cosim.build import build_one\n")
    assert {"agv_cosim.build.fmus", "pythonfmu"} <= modules


def test_fork_server_preload_imports_no_plotting_and_no_scipy():
    modules = _modules_after(
        "import importlib\n"
        "from agv_cosim.workers.pool import FORKSERVER_PRELOAD\n"
        "for name in FORKSERVER_PRELOAD:\n"
        "    importlib.import_module(name)\n")
    assert "fmpy.fmi2" in modules and "agv_cosim.workers.pool" in modules
    assert not modules & set(HEAVY)


def test_a_run_worker_starts_without_plotting_or_scipy():
    # a worker is forked from the command after it prepared the runs: it starts with
    # the command's modules, which must not include what only a figure needs
    modules = _modules_after(
        "import agv_cosim.cli, agv_cosim.pipeline, agv_cosim.workers.job\n"
        "import agv_cosim.report, agv_cosim.ssp\n"
        "from agv_cosim.report import plots, montecarlo, page\n")
    assert "agv_cosim.workers.pool" in modules and "agv_cosim.report.plots" in modules
    assert not modules & set(HEAVY)


def test_drawing_a_figure_imports_matplotlib():
    # the other side of the tests above: the figure functions do import it when called
    modules = _modules_after(
        "from agv_cosim.report import plots\n"
        "plots.sweep_metrics_figure([{'variant': 'a', 'point': {'k': 1.0}, 'status': 'complete', "
        "'metrics': {'m': 1.0}}], 'k', ['m'], {})\n")
    assert "matplotlib" in modules


@pytest.mark.parametrize("preset", [None, "3"])
def test_the_console_script_runs_openblas_on_one_thread_unless_told(preset):
    """agv-cosim's entry point sets OPENBLAS_NUM_THREADS=1 before anything imports numpy,
    and leaves a value the user set."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    if preset is not None:
        env["OPENBLAS_NUM_THREADS"] = preset
    code = ("import os, sys\nfrom agv_cosim import cli\n"
            "def main():\n"
            "    print(os.environ['OPENBLAS_NUM_THREADS'], 'numpy' in sys.modules)\n"
            "    return 0\n"
            "cli.main = main\ncli.console()\n")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120, cwd=ROOT, env=env)
    assert done.returncode == 0, done.stderr
    assert done.stdout.split() == [preset or "1", "False"]


def test_dir_shows_the_api_without_importing_it():
    # a notebook's tab completion lists dir(agv_cosim): run, open_results, ... are there
    # before their first use, and listing them imports none of their modules
    modules = _modules_after(
        "import agv_cosim\n"
        "names = dir(agv_cosim)\n"
        "missing = {'run', 'open_results', 'Results', 'load_manifest', 'AgvCosimError',\n"
        "           '__version__'} - set(names)\n"
        "assert not missing, missing\n"
        "assert set(agv_cosim.__all__) <= set(names)\n"
        "assert names == sorted(names)\n")
    assert not modules & {*HEAVY, "numpy", "fmpy", "pydantic", "agv_cosim.api",
                          "agv_cosim.manifest", "agv_cosim.pipeline"}
