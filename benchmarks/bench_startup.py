"""Benchmark: the fixed cost of one ``agv-cosim`` command against ``fmpy simulate``.

Each round runs, one after the other (paired: the ratios are taken round by round, so a
machine that drifts moves both sides):

fmpy
    ``fmpy simulate fmus/AgvVehicle.fmu --stop-time 0.001`` (the yardstick), as it
    comes and with ``OPENBLAS_NUM_THREADS=1`` ("fmpy1": how the ``agv-cosim`` script
    runs OpenBLAS, whose idle threads otherwise spin about 0.1 s of CPU in a process
    that imports numpy; the like-for-like CPU anchor);
run 1 FMU
    ``agv-cosim run`` of the vehicle alone (its position recorded), stop = 1 ms;
run loop
    ``agv-cosim run`` of the seed-000 loop (``experiments/seed000_models_abc.toml``,
    variant ``a``: 5 FMUs, its metrics and its figure), stop = 1 ms;
run loop, no plots
    the same without its ``[plots]`` tables (no figure drawn);
help, list
    ``agv-cosim --help`` and ``agv-cosim list fmus/AgvVehicle.fmu``.

Every ``run`` is a whole command: manifest read, FMUs checked, the initialisation check,
the run in its own process, the result folder written (``--quiet``). Wall time is taken
around each command; CPU time is the command's and its waited-for children's
(``RUSAGE_CHILDREN``, after minus before). It prints, per case, the median wall and CPU
time and the median of the per-round ratios against fmpy; then, from one more run of
each, the peak resident memory of the command's largest process.

``--baseline DIR`` also runs every agv-cosim case with another checkout (``DIR/.venv``
and ``DIR/fmus``, e.g. ``git worktree add DIR COMMIT`` then ``make venv fmus`` there) in
the same rounds, and prints this checkout against it. For ``run loop`` it also splits the
time after the command's main function returned: atexit handlers, then interpreter
finalisation (timestamps written by a wrapper of ``agv_cosim.cli.main``).

Run: ``.venv/bin/python benchmarks/bench_startup.py [--rounds 5] [--baseline DIR]``
"""

import argparse
import os
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _loop_manifest(root: Path, folder: Path, plots: bool) -> Path:
    text = (ROOT / "experiments" / "seed000_models_abc.toml").read_text()
    text = re.sub(r"(?m)^stop = .*$", "stop = 0.001", text)
    text = text.replace('"../fmus/', f'"{root / "fmus"}/')
    if not plots:
        text = text[:text.index("[plots]")]
    path = folder / f"loop_{'plots' if plots else 'noplots'}_{abs(hash(str(root)))}.toml"
    path.write_text(text)
    return path


def _vehicle_manifest(root: Path, folder: Path) -> Path:
    path = folder / f"vehicle_{abs(hash(str(root)))}.toml"
    path.write_text(f"""name = "vehicle_alone"
[simulation]
start = 0.0
stop = 0.001
step = 0.001
[components.vehicle]
fmu = "{root / "fmus" / "AgvVehicle.fmu"}"
[record]
variables = ["vehicle.x", "vehicle.y", "vehicle.heading"]
""")
    return path


def _cases(root: Path, folder: Path) -> dict[str, list[str]]:
    cosim = str(root / ".venv" / "bin" / "agv-cosim")
    out = str(folder / f"out_{abs(hash(str(root)))}")

    def run(manifest: Path, *extra: str) -> list[str]:
        return [cosim, "run", str(manifest), *extra, "--out", out, "--overwrite", "--quiet"]

    return {
        "run 1 FMU": run(_vehicle_manifest(root, folder)),
        "run loop": run(_loop_manifest(root, folder, True), "--variant", "a"),
        "run loop, no plots": run(_loop_manifest(root, folder, False), "--variant", "a"),
        "help": [cosim, "--help"],
        "list": [cosim, "list", str(root / "fmus" / "AgvVehicle.fmu")],
    }


#: ``agv-cosim`` as its console script runs it (``cli.console`` where there is one, else
#: ``sys.exit(cli.main())``), with the times (epoch seconds) its main function returned
#: and the last atexit handler ran written to stderr; the rest of the process's life is
#: the interpreter's finalisation.
_FINALISED = """
import atexit, sys, time
from agv_cosim import cli
atexit.register(lambda: sys.stderr.write(f"ATEXIT_END {time.time()!r}\\n"))
main = cli.main
def timed(*args):
    code = main(*args)
    sys.stderr.write(f"MAIN_END {time.time()!r}\\n")
    return code
cli.main = timed
if hasattr(cli, "console"):
    cli.console()
sys.exit(cli.main())
"""


def _finalisation(root: Path, command: list[str]) -> tuple[float, float]:
    """(s from main's return to the end of the atexit handlers, s from there to the
    process's end) of an ``agv-cosim`` command run by ``root``'s Python."""
    python = str(root / ".venv" / "bin" / "python")
    done = subprocess.run([python, "-c", _FINALISED, *command[1:]], capture_output=True,
                          text=True)
    end = time.time()
    found = dict(re.findall(r"(?m)^(MAIN_END|ATEXIT_END) (\S+)$", done.stderr))
    if done.returncode != 0 or len(found) != 2:
        sys.exit(f"finalisation run failed: {done.stderr.strip()[-500:]}")
    main_end, atexit_end = float(found["MAIN_END"]), float(found["ATEXIT_END"])
    return atexit_end - main_end, end - atexit_end


def _timed(command: list[str], env: dict[str, str] | None = None) -> tuple[float, float]:
    """(wall s, CPU s of the command and its waited-for children)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                          env=env)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        sys.exit(f"{' '.join(command)}: exit {done.returncode}: "
                 f"{done.stderr.decode(errors='replace').strip()[-500:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


#: Runs a command and prints the largest peak resident set size [KiB] of it and its
#: descendants (RUSAGE_CHILDREN's ru_maxrss: a maximum over processes, not a sum).
_PEAK = ("import resource, subprocess, sys\n"
         "subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,"
         " check=True)\n"
         "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)\n")


def _peak_rss(command: list[str]) -> float:
    """The peak resident memory [MiB] of the largest process of ``command``."""
    done = subprocess.run([sys.executable, "-c", _PEAK, *command], capture_output=True,
                          text=True, check=True)
    return int(done.stdout.split()[-1]) / 1024


def compile_package(root: Path) -> None:
    """Compile ``root``'s package to bytecode, as pip does when it installs a package (an
    editable install gets none, and with PYTHONDONTWRITEBYTECODE set every command would
    compile the sources again): each side is measured as installed."""
    subprocess.run([str(root / ".venv" / "bin" / "python"), "-m", "compileall", "-q",
                    str(root / "orchestrator" / "agv_cosim")], check=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--baseline", type=Path, metavar="DIR",
                        help="another checkout with its .venv and fmus, run in the same rounds")
    args = parser.parse_args()
    fmpy = [str(ROOT / ".venv" / "bin" / "fmpy"), "simulate",
            str(ROOT / "fmus" / "AgvVehicle.fmu"), "--stop-time", "0.001"]
    with tempfile.TemporaryDirectory(prefix="bench-startup-") as tmp:
        folder = Path(tmp)
        sides = {"new": _cases(ROOT, folder)}
        if args.baseline:
            sides["old"] = _cases(args.baseline.resolve(), folder)
        times: dict[tuple[str, str], list[tuple[float, float]]] = {}
        anchor: list[tuple[float, float]] = []
        # fmpy as agv-cosim runs OpenBLAS (one thread; cli.console): the like-for-like anchor
        one_thread = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
        anchor1: list[tuple[float, float]] = []
        for root in [ROOT] + ([args.baseline.resolve()] if args.baseline else []):
            compile_package(root)
        for side in sides.values():  # warm-up: file caches, .pyc files
            for command in side.values():
                _timed(command)
        _timed(fmpy)
        finals: dict[str, list[tuple[float, float]]] = {}
        for _ in range(args.rounds):
            anchor.append(_timed(fmpy))
            anchor1.append(_timed(fmpy, one_thread))
            for name, side in sides.items():
                for case, command in side.items():
                    times.setdefault((name, case), []).append(_timed(command))
                root = ROOT if name == "new" else args.baseline.resolve()
                finals.setdefault(name, []).append(_finalisation(root, side["run loop"]))
        peaks = {(name, case): _peak_rss(command) for name, side in sides.items()
                 for case, command in side.items() if case.startswith("run")}
        peaks[("", "fmpy simulate")] = _peak_rss(fmpy)
    med = statistics.median
    print(f"{args.rounds} rounds, medians; ratios are per round (paired), then the median")
    print(f"{'case':<22} {'side':<4} {'wall s':>7} {'CPU s':>7} {'/fmpy wall':>11} "
          f"{'/fmpy CPU':>10} {'/fmpy1 CPU':>10}"
          + (f"  {'new/old wall':>12} {'new/old CPU':>11}" if args.baseline else ""))
    print(f"{'fmpy simulate':<22} {'':<4} {med(w for w, _ in anchor):7.3f} "
          f"{med(c for _, c in anchor):7.3f}")
    print(f"{'fmpy simulate (fmpy1)':<22} {'':<4} {med(w for w, _ in anchor1):7.3f} "
          f"{med(c for _, c in anchor1):7.3f}   (OPENBLAS_NUM_THREADS=1)")
    for (name, case), samples in times.items():
        wall = med(w for w, _ in samples)
        cpu = med(c for _, c in samples)
        rw = med(w / a[0] for (w, _), a in zip(samples, anchor))
        rc = med(c / a[1] for (_, c), a in zip(samples, anchor))
        rc1 = med(c / a[1] for (_, c), a in zip(samples, anchor1))
        line = (f"{case:<22} {name:<4} {wall:7.3f} {cpu:7.3f} {rw:11.2f} {rc:10.2f} "
                f"{rc1:10.2f}")
        if name == "new" and ("old", case) in times:
            old = times[("old", case)]
            line += (f"  {med(n[0] / o[0] for n, o in zip(samples, old)):12.2f} "
                     f"{med(n[1] / o[1] for n, o in zip(samples, old)):11.2f}")
        print(line)
    for name, samples in finals.items():
        print(f"run loop, {name}: after main returned: atexit handlers "
              f"{med(a for a, _ in samples):.3f} s, then interpreter finalisation "
              f"{med(f for _, f in samples):.3f} s (medians)")
    print("peak resident memory of the command's largest process (one run each): "
          + ", ".join(f"{case}{' ' + name if name else ''} {mib:.0f} MiB"
                      for (name, case), mib in peaks.items()))


if __name__ == "__main__":
    main()
