"""Profile split: where the master's CPU per macro step goes on the seed-000 loop (issue 36).

The loop is the one of ``bench_c_host.py``: experiments/seed000_models_abc.toml variant
``a`` (5 FMUs, Gauss-Seidel at 1 ms, 9 signals every 10th step), FMUs from ``--fmus``,
run by ``simulate(plan, fast=True)`` in a fresh child process per run, once with the
compiled call path (agv_cosim/execution/compiled.py) and once with ``AGV_COSIM_NO_C=1``
(the generated Python functions calling through ctypes), runs interleaved.

Each child runs under ``perf record -F FREQ --call-graph dwarf,16384 -k mono`` (CPU-clock
samples, each with its stack unwound from DWARF call-frame information). The child
notes ``CLOCK_MONOTONIC`` at its first and last recorded row; only the samples of its
main thread between the two are counted, so loading, instantiating and the end of the
run are left out. Python 3.11 has no perf trampoline: a sample shows the C stack
(``_PyEval_EvalFrameDefault`` for any Python), so the split is made from which libraries
the stack passes through, walked from its root to its leaf:

FMI call mechanism (ctypes/libffi)
    anything under a frame of ``_ctypes`` or ``libffi`` (before the FMU's library):
    ctypes' argument conversion, libffi, and the libpython they call.
compiled path (_fmicall)
    anything under a frame of the compiled extension ``_fmicall`` (before the FMU's
    library): the calls themselves, and in a stretch the Gauss-Seidel exchange, the
    status and finite checks and the track writes that the ctypes path does in Python.
bridge/loader C
    samples whose leaf is in the FMU's loader (``<model>.so``) or bridge
    (``<model>.bridge.so``), or in libc/libm/the kernel called from there.
libpython for the bridge
    samples in libpython called by the bridge before any Python code runs: the GIL
    (PyGILState_Ensure/Release), the attribute reads and writes of the Real values,
    building argument lists, the call set-up.
FMUs' own Python (cores and adapter)
    anything under a ``_PyEval_EvalFrameDefault`` that the bridge called: the slave
    adapters and the agv_core cores (their libpython, numpy, libm).
GC
    anything under ``gc_collect_*`` (the cyclic collector), wherever it was triggered.
master's own Python
    the rest with a complete stack: the master's interpreter running the generated pass
    (ctypes path) or the Python between stretches (compiled path: recording, events,
    progress), the observer that keeps the rows, and their libpython.
stack not unwound
    samples whose stack does not reach the process's ``main`` (unwinding stopped early):
    counted apart rather than guessed.

Printed per path: the share of the counted samples per category, the share times the
child's CPU per macro step (``time.process_time`` between the first and last row,
measured under perf, so a little above an unprofiled run), the top leaf functions of
each category, and the digest of the recorded rows (the two paths must agree, else exit
status 1).

Run: ``python benchmarks/profile_split.py [--fmus fmus] [--stop 10] [--repeats 3]
[--freq 4999] [--paths compiled,ctypes] [--keep DIR] [--py-spy PATH]``. Needs ``perf``
(Debian: ``apt-get install linux-perf``) allowed to sample the process
(``perf_event_paranoid`` <= 2 for one's own processes, or root).

With ``--py-spy PATH`` (py-spy, e.g. installed into a venv of its own), one more run of
the compiled path under ``py-spy record`` splits the FMUs' own Python into the agv_core
cores and the adapters (slave scripts and ``agv_core/fmi``) by the innermost FMU frame
of each sample taken in a stretch. py-spy samples wall-clock time and sees Python frames
only, so this split is of shares within the FMUs' Python, not of the step.
"""

import argparse
import collections
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(Path(__file__).resolve().parent))

CATEGORIES = (
    "FMI call mechanism (ctypes/libffi)",
    "compiled path (_fmicall)",
    "bridge/loader C",
    "libpython for the bridge",
    "FMUs' own Python (cores and adapter)",
    "GC",
    "master's own Python",
    "stack not unwound",
)
PATHS = {"compiled": None, "ctypes": "1"}
EVAL = "_PyEval_EvalFrameDefault"
ROOTS = ("_start", "__libc_start_main", "__libc_start_call_main", "main", "Py_BytesMain")


def child(args: argparse.Namespace) -> None:
    """Run the loop once; print the monotonic times of the first and last rows."""
    from bench_c_host import digest, load_job

    from agv_cosim.execution import RowObserver, simulate

    plan = load_job("seed000", args.stop, Path(args.fmus))
    rows: list[list[float]] = []
    marks: list[tuple[float, float]] = []

    libraries: dict[str, str] = {}

    def keep(row: Sequence[Any]) -> None:
        rows.append(list(row))
        marks.append((time.clock_gettime(time.CLOCK_MONOTONIC), time.process_time()))
        if len(rows) == 1 and args.save:
            libraries.update(save_libraries(Path(args.save)))
            marks[0] = (time.clock_gettime(time.CLOCK_MONOTONIC), time.process_time())

    simulate(plan, [RowObserver(keep)], fast=True)
    (m0, c0), (m1, c1) = marks[0], marks[-1]
    print(json.dumps({"t0": m0, "t1": m1, "cpu_us": (c1 - c0) / plan.steps * 1e6,
                      "steps": plan.steps, "digest": digest(rows), "pid": os.getpid(),
                      "libraries": libraries}))


def save_libraries(folder: Path) -> dict[str, str]:
    """Copy the FMUs' loaders and bridges this process has mapped into ``folder``:
    the master deletes its extraction folders at the end of the run, and perf needs the
    libraries to unwind through them. Returns {path mapped: copy}."""
    saved: dict[str, str] = {}
    for line in Path("/proc/self/maps").read_text().splitlines():
        path = line.split(maxsplit=5)[-1] if len(line.split()) == 6 else ""
        if "/binaries/linux64/" in path and path not in saved and os.path.isfile(path):
            copy = folder / f"{len(saved)}-{os.path.basename(path)}"
            shutil.copy2(path, copy)
            saved[path] = str(copy)
    return saved


def samples(data: Path) -> Iterator[tuple[int, float, list[tuple[str, str]]]]:
    """(tid, time, frames from leaf to root as (symbol, dso)) of every sample in ``data``."""
    errors = data.with_suffix(".script-errors")
    with errors.open("w") as sink:
        done = subprocess.Popen(["perf", "script", "-i", str(data), "-F",
                                 "tid,time,ip,sym,dso", "--no-inline"], stdout=subprocess.PIPE,
                                stderr=sink, text=True, errors="replace")
    assert done.stdout is not None
    head: tuple[int, float] | None = None
    frames: list[tuple[str, str]] = []
    for line in done.stdout:
        if not line.strip():
            if head is not None:
                yield head[0], head[1], frames
            head, frames = None, []
        elif not line[0].isspace():
            parts = line.split()
            head = (int(parts[0]), float(parts[1].rstrip(":")))
        else:
            # "    7f12ab34 symbol+0x1f (/path/to/dso)"
            text = line.strip()
            dso = text[text.rfind("(") + 1:-1] if text.endswith(")") else "?"
            body = text[:text.rfind("(")].strip() if text.endswith(")") else text
            _, _, sym = body.partition(" ")
            frames.append((sym.rsplit("+0x", 1)[0], dso))
    if head is not None:
        yield head[0], head[1], frames
    if done.wait() != 0:
        raise SystemExit(f"perf script failed on {data}: "
                         f"{errors.read_text().strip()[-800:] or 'no message'}")


def kind_of(dso: str) -> str:
    name = os.path.basename(dso)
    if name.startswith("_fmicall"):
        return "fmicall"
    if name.startswith("_ctypes") or name.startswith("libffi"):
        return "ctypes"
    if name.endswith(".bridge.so") or "/binaries/linux64/" in dso:
        return "fmu"
    if name.startswith("libpython") or name.startswith("python3"):
        return "python"
    return "other"


def classify(frames: list[tuple[str, str]]) -> str:
    """The category of one sample (``frames`` from leaf to root)."""
    if not frames or not any(sym in ROOTS for sym, _ in frames[-4:]):
        return "stack not unwound"
    state = "master"
    gc = False
    for sym, dso in reversed(frames):
        kind = kind_of(dso)
        if sym.startswith("gc_collect"):
            gc = True
        if kind == "fmicall" and state == "master":
            state = "compiled"
        elif kind == "ctypes" and state == "master":
            state = "ctypes"
        elif kind == "fmu":
            state = "bridge"
        elif state == "bridge" and sym == EVAL:
            state = "fmu-py"
    if gc:
        return "GC"
    leaf = kind_of(frames[0][1])
    if state == "bridge":
        return "libpython for the bridge" if leaf == "python" else "bridge/loader C"
    return {"master": "master's own Python", "ctypes": "FMI call mechanism (ctypes/libffi)",
            "compiled": "compiled path (_fmicall)",
            "fmu-py": "FMUs' own Python (cores and adapter)"}[state]


def path_env(path: str) -> dict[str, str]:
    """The environment of a child of ``path`` (AGV_COSIM_NO_C set or not)."""
    env = dict(os.environ)
    env.pop("AGV_COSIM_NO_C", None)
    value = PATHS[path]
    if value is not None:
        env["AGV_COSIM_NO_C"] = value
    return env


def profile(path: str, args: argparse.Namespace, out: Path, keep: bool) -> dict[str, Any]:
    """One child under perf; its samples counted per category and per leaf function."""
    saved = out.with_suffix(".libs")
    saved.mkdir()
    command = ["perf", "record", "-q", "-N", "-F", str(args.freq), "-k", "mono",
               "--call-graph", "dwarf,16384", "-o", str(out), "--",
               sys.executable, __file__, "--child", "--stop", str(args.stop),
               "--fmus", args.fmus, "--save", str(saved)]
    done = subprocess.run(command, capture_output=True, text=True, env=path_env(path),
                          check=False)
    if done.returncode != 0:
        raise SystemExit(f"{path}: perf record failed: {done.stderr.strip()[-800:]}")
    info: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    counts: collections.Counter[str] = collections.Counter()
    leaves: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    # the FMU libraries back at the paths they were mapped from, while perf reads them
    made: list[Path] = []
    try:
        for original, copy in info["libraries"].items():
            top = Path(original)
            if top.exists():
                continue
            while not top.parent.exists():
                top = top.parent
            made.append(top)
            Path(original).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(copy, original)
        for tid, stamp, frames in samples(out):
            if tid != info["pid"] or not info["t0"] <= stamp <= info["t1"]:
                continue
            category = classify(frames)
            counts[category] += 1
            if frames:
                sym, dso = frames[0]
                leaves[category][f"{sym or '?'} ({os.path.basename(dso)})"] += 1
    finally:
        for top in reversed(made):
            if top.is_dir():
                shutil.rmtree(top, ignore_errors=True)
            else:
                top.unlink(missing_ok=True)
        if not keep:
            out.unlink(missing_ok=True)
            shutil.rmtree(saved, ignore_errors=True)
    if not counts:
        raise SystemExit(f"{path}: no sample of pid {info['pid']} between its first and last "
                         f"row in {out} (--keep DIR keeps it)")
    info["counts"] = counts
    info["leaves"] = leaves
    return info


def unprofiled(path: str, args: argparse.Namespace) -> dict[str, Any]:
    """The same child without perf: the CPU per macro step the shares are applied to."""
    done = subprocess.run([sys.executable, __file__, "--child", "--stop", str(args.stop),
                           "--fmus", args.fmus], capture_output=True, text=True,
                          env=path_env(path), check=False)
    if done.returncode != 0:
        raise SystemExit(f"{path}: run failed: {done.stderr.strip()[-800:]}")
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def report(path: str, runs: list[dict[str, Any]], plain: list[dict[str, Any]],
           top: int) -> None:
    counts: collections.Counter[str] = collections.Counter()
    leaves: dict[str, collections.Counter[str]] = collections.defaultdict(collections.Counter)
    for run in runs:
        counts.update(run["counts"])
        for category, tops in run["leaves"].items():
            leaves[category].update(tops)
    total = sum(counts.values())
    cpu = statistics.median(run["cpu_us"] for run in plain)
    under = statistics.median(run["cpu_us"] for run in runs)
    print(f"\n{path}: CPU per macro step {cpu:.2f} us without perf (runs: "
          + " ".join(f"{run['cpu_us']:.2f}" for run in plain)
          + f"), {under:.2f} us under perf; {total} samples")
    for category in CATEGORIES:
        n = counts.get(category, 0)
        if not n:
            continue
        share = n / total
        tops = ", ".join(f"{name} {k / n:.0%}" for name, k in leaves[category].most_common(top))
        print(f"  {category:38s} {share:6.1%} {share * cpu:6.2f} us   {tops}")


def python_split(py_spy: str, args: argparse.Namespace, out: Path) -> str:
    """One run of the compiled path under py-spy (Python frames, wall-clock samples):
    the FMUs' own Python split by the innermost FMU frame of each sample in a stretch,
    an agv_core core (``agv_core_bundle/`` but ``fmi/``) or an adapter (the slave script,
    ``agv_core_bundle/fmi/``)."""
    command = [py_spy, "record", "-r", "1000", "-f", "raw", "-o", str(out), "--",
               sys.executable, __file__, "--child", "--stop", str(args.stop),
               "--fmus", args.fmus]
    done = subprocess.run(command, capture_output=True, text=True, env=path_env("compiled"),
                          check=False)
    if done.returncode != 0:
        raise SystemExit(f"py-spy failed: {done.stderr.strip()[-800:]}")
    parts: collections.Counter[str] = collections.Counter()
    modules: collections.Counter[str] = collections.Counter()
    for line in out.read_text().splitlines():
        stack, _, count = line.rpartition(" ")
        frames = [(f.partition(" (")[0], f.rpartition(" (")[2].partition(":")[0])
                  for f in stack.split(";")]
        names = [name for name, _ in frames]
        if "_stretch.<locals>.run" not in names:
            continue
        fmu = [file for _, file in frames[names.index("_stretch.<locals>.run") + 1:]
               if "agv_core_bundle/" in file or re.fullmatch(r"agv_\w+\.py", file)]
        if not fmu:
            continue
        inner = fmu[-1]
        core = "agv_core_bundle/" in inner and "agv_core_bundle/fmi/" not in inner
        parts["cores" if core else "adapters"] += int(count)
        modules[inner.replace("agv_core_bundle/", "")] += int(count)
    total = sum(parts.values())
    if not total:
        return "\npy-spy: no sample of the FMUs' Python in a stretch"
    return (f"\nthe FMUs' own Python, compiled path, by py-spy (wall-clock samples of Python "
            f"frames, one run, {total} samples in the FMUs' Python): cores "
            f"{parts['cores'] / total:.0%}, adapters {parts['adapters'] / total:.0%}; "
            + ", ".join(f"{name} {n / total:.0%}" for name, n in modules.most_common(8)))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fmus", default=str(ROOT / "fmus"))
    parser.add_argument("--stop", type=float, default=10.0,
                        help="simulated seconds per run (default 10: 10 000 macro steps)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--freq", type=int, default=4999, help="samples per CPU second")
    parser.add_argument("--paths", default="compiled,ctypes")
    parser.add_argument("--top", type=int, default=4, help="leaf functions per category")
    parser.add_argument("--keep", help="keep the perf.data files in this folder")
    parser.add_argument("--py-spy", help="py-spy executable: also split the FMUs' Python "
                        "into cores and adapters (one more run under py-spy)")
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--save", help=argparse.SUPPRESS)
    args = parser.parse_args()
    args.fmus = str(Path(args.fmus).resolve())
    if args.child:
        child(args)
        return 0
    if shutil.which("perf") is None:
        raise SystemExit("profile_split: no perf on PATH (Debian: apt-get install linux-perf)")
    paths = args.paths.split(",")
    for path in paths:
        if path not in PATHS:
            raise SystemExit(f"profile_split: --paths: unknown path {path!r} "
                             f"(known: {', '.join(PATHS)})")
    tmp = Path(args.keep or tempfile.mkdtemp(prefix="profile_split_"))
    tmp.mkdir(parents=True, exist_ok=True)
    runs: dict[str, list[dict[str, Any]]] = {path: [] for path in paths}
    plain: dict[str, list[dict[str, Any]]] = {path: [] for path in paths}
    try:
        for repeat in range(args.repeats):
            for path in paths:
                runs[path].append(profile(path, args, tmp / f"{path}-{repeat}.data",
                                          keep=bool(args.keep)))
                plain[path].append(unprofiled(path, args))
        spy = python_split(args.py_spy, args, tmp / "py-spy.txt") if args.py_spy else ""
    finally:
        if not args.keep:
            shutil.rmtree(tmp, ignore_errors=True)
    print(f"seed 000 model a, {runs[paths[0]][0]['steps']} macro steps per run, "
          f"{args.repeats} runs per path under perf -F {args.freq} (DWARF stacks) and "
          f"{args.repeats} without, interleaved; counted: the main thread from the first "
          f"recorded row to the last; us = share x CPU per step without perf")
    for path in paths:
        report(path, runs[path], plain[path], args.top)
    if spy:
        print(spy)
    digests = {run["digest"] for path in paths for run in runs[path] + plain[path]}
    if len(digests) != 1:
        print(f"\nRECORDINGS DIFFER: {sorted(digests)}")
        return 1
    print(f"\nrecordings bit-identical in every run (digest {digests.pop()})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
