"""Integration tier: standalone FMUs (``agv-cosim build --standalone``) on a machine without
Python.

Three FMUs are built standalone: the vehicle (no package beyond the standard library),
the preview + LQ controller (scipy, python-control and what control imports) and the FMI
3.0 twin of the fuzzy PD (scikit-fuzzy). fmusim runs each to its stop time with its
reference inputs inside a mount namespace (``unshare -m``, as root) in which every Python
is hidden: empty file systems over /root (pyenv), /work and /home (checkouts and venvs),
/tmp, /opt, /usr/local and Debian's Python folders, /dev/null over every python
executable and libpython. The FMU's loader must then start the FMU's own runtime, and the
output must equal the FMU's shipped reference. No path of the building machine may
appear in any file of the FMU, and fmpy (a Python host) must run a standalone FMU with
its own interpreter.
"""

import json
import os
import shutil
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import numpy as np
import pytest

from agv_cosim.build import build_one, slave_script
from agv_cosim.build.standalone import distribution_files

from fmusim_host import assert_matches, read_output, reference_of, unavailable

pytestmark = pytest.mark.interop

ROOT = Path(__file__).resolve().parents[2]
#: (slave script, FMI version)
FMUS = [("agv_vehicle", 2), ("agv_preview_lq", 2), ("agv_fuzzy_pd", 3)]

#: Run as root under `unshare -m`: hide every Python, stage the test's files in /mnt, run.
HIDE = r"""
set -e
stage=$1; shift
mount --make-rprivate /
mount -t tmpfs agv-stage /mnt
cp -a "$stage"/. /mnt/
for d in /tmp /root /work /home /opt /srv /usr/local /var/tmp \
         /usr/lib/python3* /usr/share/python3*; do
  if [ -d "$d" ]; then mount -t tmpfs agv-hidden "$d"; fi
done
for f in /usr/bin/python* /bin/python* /usr/lib/*-linux-gnu/libpython*; do
  if [ -e "$f" ] && [ ! -d "$f" ]; then mount --bind /dev/null "$f"; fi
done
cd /mnt
exec env -i PATH=/usr/bin:/bin LANG=C HOME=/mnt "$@"
"""

#: Inside the namespace: show that no Python is left, then run fmusim on each FMU.
INSIDE = r"""
for p in python3 python3.11 python; do
  if command -v $p >/dev/null && $p -c 1 2>/dev/null; then echo "PYTHON FOUND: $p"; fi
done
for fmu in *.fmu; do
  name=${fmu%.fmu}
  set -- --logging-on --output-file "out_$name.csv"
  if [ -f "in_$name.csv" ]; then set -- "$@" --input-file "in_$name.csv"; fi
  ./fmusim "$@" "$fmu" > "log_$name.txt" 2>&1
  echo "$name $?" >> status.txt
done
cp status.txt out_*.csv log_*.txt "$RESULTS"/
"""


@pytest.fixture(scope="module")
def standalone_fmus(tmp_path_factory):
    """The FMUS built standalone: stem -> FMU path."""
    out = tmp_path_factory.mktemp("standalone")
    return {stem: build_one(slave_script(stem), out / f"fmi{version}", fmi_version=version,
                            standalone=True).fmu
            for stem, version in FMUS}


def test_standalone_fmus_run_where_no_python_is(fmusim, standalone_fmus, tmp_path):
    if os.geteuid() != 0 or shutil.which("unshare") is None:
        unavailable("needs root and unshare (a mount namespace hides every Python)")
    stage = tmp_path / "stage"
    stage.mkdir()
    shutil.copy2(fmusim, stage / "fmusim")
    references = {}
    for fmu in standalone_fmus.values():
        name = fmu.stem
        shutil.copy2(fmu, stage / fmu.name)
        folder = tmp_path / f"ref_{name}"
        folder.mkdir()
        input_csv, references[name] = reference_of(fmu, folder)
        if input_csv is not None:
            shutil.copy2(input_csv, stage / f"in_{name}.csv")
    # the results come back through /dev/shm, which the namespace does not hide
    results = tmp_path / "results"
    results.mkdir()
    script = tmp_path / "hide.sh"
    script.write_text(HIDE)
    inside = stage / "inside.sh"
    inside.write_text(INSIDE)
    keep = Path("/dev/shm") / f"agv-standalone-{os.getpid()}"
    keep.mkdir()
    try:
        done = subprocess.run(["unshare", "-m", "sh", str(script), str(stage), f"RESULTS={keep}",
                               "sh", "inside.sh"], capture_output=True, text=True, timeout=1800)
        assert done.returncode == 0, done.stderr[-3000:]
        for path in keep.iterdir():
            if path.is_file():
                shutil.copy2(path, results / path.name)
    finally:
        shutil.rmtree(keep, ignore_errors=True)
    assert "PYTHON FOUND" not in done.stdout
    status = dict(line.split() for line in (results / "status.txt").read_text().splitlines())
    for name, reference in references.items():
        log = (results / f"log_{name}.txt").read_text()
        assert status[name] == "0", log[-3000:]
        assert "(the FMU's own Python runtime)" in log, log[-2000:]
        assert_matches(read_output(results / f"out_{name}.csv"), reference)


def _machine_paths():
    """Paths of this machine that a portable FMU must not contain."""
    paths = {str(ROOT), sys.prefix, sys.base_prefix, os.path.realpath(sys.base_prefix),
             os.path.realpath(sys.executable), "/root/.pyenv",
             sysconfig.get_config_var("abs_builddir") or "", str(Path.home() / ".pyenv")}
    return sorted(p for p in paths if len(p) > 5)


def test_no_path_of_the_building_machine_in_a_standalone_fmu(standalone_fmus, tmp_path):
    """Every file of every standalone FMU, text or binary, unpacked and searched."""
    needles = [p.encode() for p in _machine_paths()]
    found = []
    for fmu in standalone_fmus.values():
        with zipfile.ZipFile(fmu) as archive:
            for info in archive.infolist():
                data = archive.read(info)
                found += [f"{fmu.name}:{info.filename}: {n.decode()}" for n in needles
                          if n in data]
    assert not found, "\n".join(found[:20])


def test_standalone_fmus_carry_only_what_they_use_and_its_bytecode(standalone_fmus):
    """What is left out is left out: no tests, headers or Tk in the runtime; of the
    standard library and of each distribution only the files the slave uses (the vehicle,
    standard library only, carries no numpy, no asyncio, email or unittest; the preview
    controller a part of scipy's files); every Python source with its checked hash-based
    bytecode (PEP 552) in __pycache__; needsExecutionTool="false" and no binary of another
    platform than the runtime's; the vehicle under 6 MB (6.7 MB when the whole standard
    library went in)."""
    for fmu in standalone_fmus.values():
        with zipfile.ZipFile(fmu) as archive:
            names = archive.namelist()
            md = archive.read("modelDescription.xml").decode()
            pycs = {n: archive.read(n) for n in names if n.endswith(".pyc")}
        runtime = [n for n in names if "/python/" in n and n.startswith("binaries/")]
        assert runtime, fmu.name
        assert not [n for n in runtime if n.endswith(".h")]
        assert not [n for n in runtime if "/tests/" in n or "/test/" in n
                    or "/tkinter/" in n or "lib-dynload/_tkinter" in n]
        sources = [n for n in names if n.endswith(".py")]
        assert sources and not [n for n in sources if _pyc_of(n) not in pycs]
        # flags 0b11: hash-based and checked
        assert {int.from_bytes(data[4:8], "little") for data in pycs.values()} == {3}
        assert 'needsExecutionTool="false"' in md
        platform = "x86_64-linux" if 'fmiVersion="3.0"' in md else "linux64"
        assert {n.split("/")[1] for n in names if n.startswith("binaries/")} == {platform}
    with zipfile.ZipFile(standalone_fmus["agv_vehicle"]) as archive:
        vehicle = archive.namelist()
    assert not [n for n in vehicle if "/site-packages/numpy/" in n or "/asyncio/" in n
                or "/email/" in n or "/unittest/" in n]
    assert standalone_fmus["agv_vehicle"].stat().st_size < 6e6
    with zipfile.ZipFile(standalone_fmus["agv_preview_lq"]) as archive:
        shipped = {n.split("/site-packages/", 1)[1] for n in archive.namelist()
                   if "/site-packages/scipy/" in n and n.endswith(".py")}
    installed = {relative for _, relative in distribution_files("scipy")
                 if relative.endswith(".py")}
    assert shipped and shipped < installed


def _pyc_of(name):
    folder, _, file = name.rpartition("/")
    cached = f"__pycache__/{file[:-3]}.{sys.implementation.cache_tag}.pyc"
    return f"{folder}/{cached}" if folder else cached


def test_a_standalone_build_leaves_nothing_in_the_temporary_folder(tmp_path):
    """The runtime is assembled in a temporary folder that the build removes when it
    ends (it stayed behind, ~21 MB, in /tmp)."""
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    code = ("import sys\nfrom agv_cosim.build import build_fmus, slave_script\n"
            "build_fmus(sys.argv[1], [slave_script('agv_gyro')], standalone=True)\n")
    done = subprocess.run([sys.executable, "-c", code, str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=900,
                          env={**os.environ, "TMPDIR": str(scratch)})
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "out" / "AgvGyro.fmu").is_file()
    assert list(scratch.iterdir()) == []


PYTHON_HOST = """
import json, sys
import fmpy
from fmpy.util import read_csv
fmu, inputs = sys.argv[1], sys.argv[2]
result = fmpy.simulate_fmu(fmu, input=read_csv(inputs) if inputs else None,
                           output_interval=float(sys.argv[3]))
own = [p for p in sys.path if p.endswith("/python/lib/python3.%d/site-packages"
                                         % sys.version_info.minor)]
print(json.dumps({"own_packages_last": bool(own) and sys.path[-1] == own[-1],
                  "columns": {n: result[n].tolist() for n in result.dtype.names}}))
"""


def test_a_python_host_runs_a_standalone_fmu_in_its_own_interpreter(standalone_fmus,
                                                                    tmp_path):
    """fmpy loads the standalone preview controller: the FMU's loader finds the host's
    Python in the process and uses it (one interpreter, never two); the FMU's packages
    are appended to sys.path after the host's. Output: the shipped reference."""
    fmu = standalone_fmus["agv_preview_lq"]
    input_csv, reference = reference_of(fmu, tmp_path)
    step = float(np.diff(reference["time"][:2])[0])
    script = tmp_path / "host.py"
    script.write_text(PYTHON_HOST)
    done = subprocess.run([sys.executable, str(script), str(fmu), str(input_csv or ""),
                           repr(step)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    answer = json.loads(done.stdout.strip().splitlines()[-1])
    assert answer["own_packages_last"]
    table = {k: np.array(v) for k, v in answer["columns"].items()}
    assert_matches(table, reference)
