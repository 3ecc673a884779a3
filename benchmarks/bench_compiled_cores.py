"""Benchmark: the FMUs' own Python per macro step with the two costliest cores compiled.

The two costliest cores of the seed-000 loop (profile of the floor below: cProfile
cumulative time per step) are the steering actuator (``agv_core/steering/actuator.py``,
model a's dead-time history) and the sensors (``agv_core/sensors/sensors.py``, the
vision sensor's sampling). This script measures what compiling those two modules with
mypyc and with Cython (pure-Python mode, the same source, no annotations added) saves:

1. The seed-000 FMUs (``--fmus DIR``, built earlier with ``agv-cosim build --out DIR``;
   else built here) are copied three times: as built, with the two modules compiled by
   mypyc, with them compiled by Cython. A module is compiled under the name the FMU's
   boot loader imports it by (``agv_core_<BUILD_ID>.steering.actuator``) and the
   extension is put beside the ``.py`` in ``resources/agv_core_bundle/`` (Python's import
   takes an extension module before the source; mypyc's shared runtime library goes to
   ``resources/``). For mypyc, every ``def __init__(...):`` gets ``-> None`` and every
   unannotated property getter ``-> Any`` first (the same code; mypyc's analysis stops
   without), and mypy's errors count only in the compiled modules (the modules they
   import stay interpreted); ``--as-is`` leaves the sources and mypy's checks as they
   are. Cython compiles the source as it is. The compilers run in the venv
   ``--compiler-venv`` (a throwaway venv with mypy and Cython; nothing is installed by
   this script).
2. ``benchmarks/bench_step.py --child floor`` runs each copy in a fresh child (the slave
   classes in plain Python, the master's Gauss-Seidel order: the FMUs' own Python per
   step, no FMI), rounds interleaved; medians of the CPU per macro step, the ratio to
   the pure-Python copy (target for wiring a compiler into the build: >= 2x cheaper), and
   the digest of the recorded rows (must be equal: bit-identical results).

Run: ``python benchmarks/bench_compiled_cores.py --compiler-venv VENV [--fmus DIR]
[--modules steering/actuator.py sensors/sensors.py] [--compilers mypyc cython]
[--rounds 5] [--stop 10] [--callgrind] [--as-is]``.
"""

import argparse
import json
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MODULES = ("steering/actuator.py", "sensors/sensors.py")
BUNDLE = "resources/agv_core_bundle/"
#: the FMUs of seed 000 model a (the others are copied as built)
LOOP = ("AgvVehicle", "AgvSteeringA", "AgvVisionSensor", "AgvSteerSensor", "AgvStateFeedback")


class CompileFailed(Exception):
    pass


def typed_inits(source):
    """The source with ``-> None`` on every untyped ``def __init__(...):``: mypyc's
    self-leak analysis fails on a call of an untyped ``__init__`` (``super().__init__``
    included); the code is otherwise the same."""
    lines, in_init = [], False
    for line in source.splitlines(keepends=True):
        if re.match(r"\s+def __init__\(", line):
            in_init = True
        if in_init and line.rstrip().endswith(":"):
            in_init = False
            if "->" not in line:
                line = re.sub(r"\):(\s*)$", r") -> None:\1", line)
        lines.append(line)
    return "".join(lines)


def typed_properties(source: str) -> str:
    """The source with ``-> Any`` on every unannotated property getter (mypyc stops with
    an internal error, "Expected return type annotation for property", without) and
    ``from typing import Any`` at its top; the code is otherwise the same."""
    lines: list[str] = []
    changed = property_next = False
    for line in source.splitlines(keepends=True):
        if property_next and re.match(r"\s+def \w+\(self\):\s*$", line):
            line = re.sub(r"\):(\s*)$", r") -> Any:\1", line)
            changed = True
        property_next = line.strip() == "@property"
        lines.append(line)
    if not changed:
        return source
    text = "".join(lines)
    first = re.search(r"(?m)^(import |from (?!__future__ ))", text)
    at = first.start() if first else 0
    return text[:at] + "from typing import Any\n" + text[at:]


def mypy_config(package: Path, present: list[str], check_all: bool) -> str:
    """mypy's settings for mypyc: missing stubs ignored; unless ``check_all``, errors
    only in the modules being compiled (the others stay interpreted)."""
    text = "[mypy]\nignore_missing_imports = True\ndisable_error_code = var-annotated\n"
    if not check_all:
        text += "ignore_errors = True\n"
        for module in present:
            name = package.name + "." + module.removesuffix(".py").replace("/", ".")
            text += f"\n[mypy-{name}]\nignore_errors = False\n"
    return text


def compile_fmu(fmu, out, compiler, venv, work, modules=MODULES, as_is=False):
    """Copy ``fmu`` to ``out`` with ``modules`` compiled by ``compiler`` where it has them."""
    with zipfile.ZipFile(fmu) as archive:
        names = archive.namelist()
        present = [m for m in modules if BUNDLE + m in names]
        if not present or fmu.stem not in LOOP:
            shutil.copy(fmu, out)
            return []
        tag = archive.read(BUNDLE + "BUILD_ID").decode().strip()
        package = work / f"agv_core_{tag}"
        for name in names:
            if name.startswith(BUNDLE) and not name.endswith("/"):
                target = package / name[len(BUNDLE):]
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_bytes(archive.read(name))
    sources = [str(package.relative_to(work) / m) for m in present]
    if compiler == "mypyc" and not as_is:
        for module in present:
            path = package / module
            path.write_text(typed_properties(typed_inits(path.read_text())))
    # mypy checks what the modules import; scipy and numpy's stubs are not needed here
    (work / "mypy.ini").write_text(mypy_config(package, present, as_is))
    if compiler == "mypyc":
        command = [str(venv / "bin" / "mypyc"), *sources]
    else:
        command = [str(venv / "bin" / "cythonize"), "-i", "-3", "-q", *sources]
    done = subprocess.run(command, cwd=work, capture_output=True, text=True)
    if done.returncode != 0:
        lines = (done.stderr.strip() or done.stdout.strip() or "no output").splitlines()
        # the compiler's own error line, not the notes that may follow it
        errors = [line for line in lines if re.search(r"(error|Error):", line)]
        last = (errors or lines)[-1]
        raise CompileFailed(f"{compiler} failed on {fmu.name}: {last}")
    extras = {}
    for library in package.rglob("*.so"):
        extras[BUNDLE + str(library.relative_to(package))] = library.read_bytes()
    for library in work.glob("*__mypyc*.so"):  # mypyc's runtime, a top-level module
        extras["resources/" + library.name] = library.read_bytes()
    with zipfile.ZipFile(fmu) as source, zipfile.ZipFile(out, "w",
                                                         zipfile.ZIP_DEFLATED) as target:
        for item in source.infolist():
            target.writestr(item, source.read(item.filename))
        for name, data in extras.items():
            target.writestr(name, data)
    return sorted(extras)


def write_manifest(fmus, folder, stop):
    text = (ROOT / "experiments" / "seed000_models_abc.toml").read_text()
    text = re.sub(r'"\.\./fmus/(\w+)\.fmu"', lambda m: f'"{Path(fmus) / m.group(1)}.fmu"',
                  text)
    text = re.sub(r"(?m)^stop = [0-9.]+", f"stop = {float(stop)!r}", text)
    manifest = folder / "loop.toml"
    manifest.write_text(text)
    return manifest


def floor(manifest):
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "bench_step.py"),
                           "--child", "floor", str(manifest)], capture_output=True,
                          text=True, cwd=manifest.parent)
    if done.returncode != 0:
        raise SystemExit(f"floor child failed on {manifest}: {done.stderr[-3000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--compiler-venv", type=Path, required=True,
                        help="a venv with mypy (mypyc) and Cython installed")
    parser.add_argument("--fmus", type=Path, help="FMUs built by this checkout (a folder)")
    parser.add_argument("--modules", nargs="+", default=list(MODULES),
                        help=f"the modules to compile (default: {' '.join(MODULES)})")
    parser.add_argument("--compilers", nargs="+", default=["mypyc", "cython"])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--as-is", action="store_true",
                        help="mypyc: the sources as they are (no -> None / -> Any added) and "
                        "mypy's errors in every module they import")
    parser.add_argument("--callgrind", action="store_true",
                        help="count instructions per macro step (bench_step.py's callgrind "
                        "child, one per copy) instead of timing rounds")
    parser.add_argument("--stop", type=float, default=10.0, help="simulated time [s]")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench_cores_") as tmp:
        tmp = Path(tmp)
        fmus = args.fmus
        if fmus is None:
            fmus = tmp / "built"
            subprocess.run([sys.executable, "-m", "agv_cosim.cli", "build", "--out",
                            str(fmus)], check=True, cwd=ROOT, capture_output=True)
        manifests = {"python": write_manifest(fmus, tmp, args.stop)}
        for compiler in args.compilers:
            folder = tmp / compiler
            folder.mkdir()
            try:
                for fmu in sorted(Path(fmus).glob("*.fmu")):
                    work = tmp / "work" / compiler / fmu.stem
                    work.mkdir(parents=True)
                    compile_fmu(fmu, folder / fmu.name, compiler,
                                args.compiler_venv.resolve(), work, args.modules, args.as_is)
            except CompileFailed as error:
                print(f"  {error}")
                continue
            (folder / "run").mkdir()
            manifests[compiler] = write_manifest(folder, folder / "run", args.stop)
        if args.callgrind:
            sys.path.insert(0, str(ROOT / "benchmarks"))
            import bench_step

            library = tmp / "callgrind_control.so"
            (tmp / "callgrind_control.c").write_text(bench_step.CALLGRIND_CONTROL)
            subprocess.run(["gcc", "-shared", "-fPIC", "-O2", "-o", str(library),
                            str(tmp / "callgrind_control.c")], check=True)
            env = bench_step.env_for(ROOT)
            counts = {kind: bench_step.run_callgrind("floor", manifest, env, str(library),
                                                     args.stop, tmp)
                      for kind, manifest in manifests.items()}
            print(f"seed 000 model a floor, instructions per macro step (callgrind), "
                  f"{args.stop:g} s simulated:")
            for kind, count in counts.items():
                print(f"  {kind:7s} {count:10.0f}   python / {kind}: "
                      f"{counts['python'] / count:.2f}x")
            return 0
        results = {kind: [] for kind in manifests}
        for _ in range(args.rounds):
            for kind, manifest in manifests.items():
                results[kind].append(floor(manifest))
        n = int(round(args.stop / 0.001))
        print(f"seed 000 model a floor (the FMUs' Python, no FMI), {n} macro steps, "
              f"{args.rounds} rounds interleaved; median CPU per macro step:")
        base = statistics.median(r["cpu"] for r in results["python"])
        for kind, runs in results.items():
            cpu = statistics.median(r["cpu"] for r in runs)
            print(f"  {kind:7s} {cpu * 1e6:7.2f} us   python / {kind}: {base / cpu:.2f}x")
        digests = {kind: {r["digest"] for r in runs} for kind, runs in results.items()}
        if len({d for ds in digests.values() for d in ds}) != 1:
            print(f"  recorded rows DIFFER: {digests}")
            return 1
        print("  recorded rows: bit-identical in every run")
    return 0


if __name__ == "__main__":
    sys.exit(main())
