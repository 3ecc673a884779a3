"""The Reference FMUs' fmusim as a test host: built from ../shared, run on an FMU with its
reference inputs, its output compared with the FMU's shipped reference (test_fmusim.py,
test_standalone.py beside it). Test support, not part of agv_cosim.

fmusim (Reference FMUs v0.0.39, BSD-2) is built from
``../shared/third-party/Reference-FMUs-v0.0.39`` (never copied into the repository) with
gcc against Debian's libxml2, minizip and sundials dev packages (``make test-deps``
installs them; ``make test`` depends on it). Its ``--final-fmu-state-file`` frees the saved
state with ``FMUState`` where ``&FMUState`` is meant (fmusim/FMIUtil.c, FMI 2.0 and 3.0);
the copy built here has that fixed.
"""

import csv
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]
SOURCES = Path(os.environ.get("AGV_FMUSIM_SOURCES",
                              ROOT.parent / "shared" / "third-party" /
                              "Reference-FMUs-v0.0.39"))
RTOL, ATOL = 1e-9, 1e-12
REFERENCE_DIR = "extra/org.fmi-standard.fmi-ls-ref"

#: What fmusim needs from the machine (Debian packages, `make test-deps`).
LIBRARIES = ["-lxml2", "-lminizip", "-lz", "-lsundials_cvode", "-lsundials_nvecserial",
             "-lsundials_sunmatrixdense", "-lsundials_sunlinsoldense", "-ldl", "-lm"]
FMUSIM_SOURCES = ["csv.c", "FMIUtil.c", "FMIEuler.c", "FMICVode.c", "FMIModelDescription.c",
                  "FMIRecorder.c", "FMIZip.c", "FMISimulation.c", "FMIStaticInput.c",
                  "FMIBuildDescription.c", "FMI1CSSimulation.c", "FMI1MESimulation.c",
                  "FMI2CSSimulation.c", "FMI2MESimulation.c", "FMI3CSSimulation.c",
                  "FMI3MESimulation.c", "fmusim.c", "miniunzip.c", "../src/FMI.c",
                  "../src/FMI1.c", "../src/FMI2.c", "../src/FMI3.c",
                  "../src/structured_variable_name.yy.c",
                  "../src/structured_variable_name.tab.c"]
#: fmusim's host bug: the saved state is freed through its value, not its address.
STATE_BUG = [("FMI2FreeFMUstate(S, FMUState)", "FMI2FreeFMUstate(S, &FMUState)"),
             ("FMI3FreeFMUState(S, FMUState)", "FMI3FreeFMUState(S, &FMUState)")]

#: A C program's environment with this test's venv active (no Python variables otherwise).
HOST_ENV = {"PATH": "/usr/bin:/bin", "LANG": "C", "VIRTUAL_ENV": sys.prefix,
            **{k: v for k, v in os.environ.items()
               if k.startswith(("OPENBLAS_", "OMP_", "MKL_"))}}


def unavailable(reason):
    """Skip on a developer machine; in CI (CI=true) a missing host is a failure."""
    if os.environ.get("CI"):
        pytest.fail(f"{reason} (CI must run the fmusim tests: `make test-deps`)")
    pytest.skip(reason)


def build_fmusim(build):
    """fmusim built in folder ``build`` from the shared sources, its state bug fixed in
    the copy; its path. Skips (fails in CI) when it cannot be built here."""
    if not (SOURCES / "fmusim" / "fmusim.c").is_file():
        unavailable(f"fmusim sources not found at {SOURCES}")
    if shutil.which("gcc") is None:
        unavailable("gcc is not installed")
    for part in ("fmusim", "src", "include"):
        shutil.copytree(SOURCES / part, build / part)
    util = build / "fmusim" / "FMIUtil.c"
    text = util.read_text()
    for wrong, right in STATE_BUG:
        assert text.count(wrong) == 2, f"fmusim's FMIUtil.c changed: {wrong!r}"
        text = text.replace(wrong, right)
    util.write_text(text)
    target = build / "fmusim" / "fmusim"
    done = subprocess.run(["gcc", "-O1", "-w", "-I.", "-I../include", "-I/usr/include/libxml2",
                           "-I/usr/include/minizip", '-DFMUSIM_VERSION="0.0.39"',
                           # Debian's sundials is 6.4; fmusim calls the 7.x context API
                           "-DSUN_COMM_NULL=NULL", "-o", str(target), *FMUSIM_SOURCES,
                           *LIBRARIES], cwd=build / "fmusim", capture_output=True, text=True)
    if done.returncode != 0:
        if re.search(r"No such file|cannot find -l", done.stderr):
            unavailable("fmusim cannot be built: libxml2/minizip/sundials dev packages "
                         "missing (`make test-deps`): " + done.stderr.strip().splitlines()[-1])
        pytest.fail(f"fmusim does not build:\n{done.stderr[-3000:]}")
    return target


def _reference(fmu, folder):
    """(input CSV or None, reference rows as a structured array) shipped in ``fmu``."""
    with zipfile.ZipFile(fmu) as archive:
        names = archive.namelist()
        out = next(n for n in names if n.startswith(REFERENCE_DIR) and n.endswith("_out.csv"))
        ins = [n for n in names if n.startswith(REFERENCE_DIR) and n.endswith("_in.csv")]
        archive.extract(out, folder)
        if ins:
            archive.extract(ins[0], folder)
    reference = np.genfromtxt(folder / out, delimiter=",", names=True)
    return (folder / ins[0] if ins else None), reference


def read_output(path):
    """fmusim's output CSV as {column: array}."""
    with open(path) as handle:
        rows = list(csv.reader(handle))
    header = [h.strip('"') for h in rows[0]]
    values = np.array([[float(x) for x in row] for row in rows[1:]])
    return {name: values[:, k] for k, name in enumerate(header)}


def reference_of(fmu, folder):
    """(input CSV or None, reference rows as a structured array) shipped in ``fmu``."""
    return _reference(fmu, folder)


def run_fmusim(fmusim, fmu, folder, *options, valgrind=None):
    """Run fmusim on ``fmu`` with the reference inputs; (process, output table, reference)."""
    input_csv, reference = _reference(fmu, folder)
    output = folder / "out.csv"
    command = [str(fmusim), "--output-file", str(output), *options]
    if input_csv is not None:
        command += ["--input-file", str(input_csv)]
    command.append(str(fmu))
    done = subprocess.run([*(valgrind or []), *command], capture_output=True, text=True,
                          env=HOST_ENV, timeout=1800)
    table = None
    # under valgrind, 99 is valgrind's status for reported errors (the caller sorts them)
    if done.returncode in ((0, 99) if valgrind else (0,)) and output.is_file():
        table = read_output(output)
    return done, table, reference


def assert_matches(table, reference, since=None):
    """Every reference column equal within the tolerance (rows at or after ``since``)."""
    ref_time = reference["time"]
    keep = np.ones(len(ref_time), bool) if since is None else ref_time >= since - 1e-12
    assert np.allclose(table["time"], ref_time[keep], rtol=0, atol=1e-12)
    for name in reference.dtype.names[1:]:
        assert name in table, f"fmusim did not record {name}"
        assert np.allclose(table[name], reference[name][keep], rtol=RTOL, atol=ATOL), name


