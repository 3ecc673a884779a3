"""Benchmark: ``--jobs N`` efficiency on a sweep, T(jobs 1) / (N x T(jobs N)).

The seed-000 loop (``experiments/seed000_models_abc.toml`` variant ``a``, 5 FMUs, its
metrics and figure; ``--no-plots``: without ``[plots]``) with ``stop`` = ``--stop``
(default 2 s, 2000 steps of 1 ms), swept over ``--runs`` values of ``vehicle.v0``
(default 32). Each round runs the whole command
(``agv-cosim run ... --quiet``) with ``--jobs 1`` and then ``--jobs N``, and checks that
the two result folders hold the same bytes (see :func:`_same`). It
prints each round's wall and CPU times (the command and its children, ``RUSAGE_CHILDREN``)
and efficiency, and the median efficiency.

``--baseline DIR`` also runs the same with another checkout (``DIR/.venv`` and
``DIR/fmus``) in each round, right after this one (paired), and prints its efficiency and
this checkout's ``--jobs N`` wall time against it.

Run: ``.venv/bin/python benchmarks/bench_jobs.py [--runs 32] [--stop 2] [--jobs 2]
[--rounds 3] [--baseline DIR]``
"""

import argparse
import filecmp
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_startup import compile_package  # this folder: sys.path[0] of a script

ROOT = Path(__file__).resolve().parent.parent


def _manifest(folder: Path, runs: int, stop: float, plots: bool, root: Path = ROOT) -> Path:
    text = (ROOT / "experiments" / "seed000_models_abc.toml").read_text()
    if not plots:
        text = text[:text.index("[plots]")]
    text = re.sub(r"(?m)^stop = .*$", f"stop = {stop!r}", text)
    text = text.replace('"../fmus/', f'"{root / "fmus"}/')
    values = ", ".join(repr(1.0 + 0.01 * i) for i in range(runs))
    text += f'\n[sweep]\n"vehicle.v0" = [{values}]\n'
    path = folder / f"jobs_sweep_{abs(hash(str(root)))}.toml"
    path.write_text(text)
    return path


def _run(manifest: Path, out: Path, jobs: int, root: Path = ROOT) -> tuple[float, float]:
    """(wall s, CPU s of the command and its children)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([str(root / ".venv" / "bin" / "agv-cosim"), "run", str(manifest),
                           "--variant", "a", "--jobs", str(jobs), "--out", str(out),
                           "--overwrite", "--quiet"], capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        sys.exit(f"--jobs {jobs}: exit {done.returncode}: {done.stderr.strip()[-500:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def _same(a: Path, b: Path) -> bool:
    """The two result folders hold the same files with the same bytes, but timings.csv
    (the one file of measured times)."""
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    if files != sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file()):
        return False
    return all(filecmp.cmp(a / name, b / name, shallow=False)
               for name in files if name.name != "timings.csv")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=32)
    parser.add_argument("--stop", type=float, default=2.0)
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--no-plots", action="store_true",
                        help="without the manifest's [plots] (no signals.png; the page's "
                             "sweep figure is still drawn)")
    parser.add_argument("--baseline", type=Path,
                        help="another checkout, run in the same rounds (paired)")
    args = parser.parse_args()
    sides = [("new", ROOT)] + ([("old", args.baseline.resolve())] if args.baseline else [])
    efficiencies: dict[str, list[float]] = {name: [] for name, _ in sides}
    walls: dict[str, list[float]] = {name: [] for name, _ in sides}
    with tempfile.TemporaryDirectory(prefix="bench-jobs-") as tmp:
        folder = Path(tmp)
        manifests = {name: _manifest(folder, args.runs, args.stop, not args.no_plots, root)
                     for name, root in sides}
        for _, root in sides:
            compile_package(root)
        print(f"{args.runs} runs of {args.stop:g} s (seed000 variant a), --jobs 1 against "
              f"--jobs {args.jobs}")
        for round_ in range(1, args.rounds + 1):
            for name, root in sides:
                one, cpu_one = _run(manifests[name], folder / "one", 1, root)
                many, cpu_many = _run(manifests[name], folder / "many", args.jobs, root)
                same = _same(folder / "one", folder / "many")
                efficiency = one / (args.jobs * many)
                efficiencies[name].append(efficiency)
                walls[name].append(many)
                print(f"round {round_} {name}: --jobs 1 {one:.2f} s wall ({cpu_one:.2f} s "
                      f"CPU), --jobs {args.jobs} {many:.2f} s wall ({cpu_many:.2f} s CPU), "
                      f"efficiency {efficiency:.1%}, result folders "
                      f"{'identical' if same else 'DIFFER'}")
                # older code may write measured times into other files (run.json): only
                # this checkout's folders must be the same bytes
                if not same and name == "new":
                    sys.exit("the result folders differ")
    for name, _ in sides:
        print(f"{name}: median efficiency {statistics.median(efficiencies[name]):.1%} "
              "(target >= 85 %)")
    if args.baseline:
        ratios = [a / b for a, b in zip(walls["new"], walls["old"])]
        print(f"--jobs {args.jobs} wall, new / old: median {statistics.median(ratios):.2f} "
              f"(per round: {', '.join(f'{r:.2f}' for r in ratios)})")

if __name__ == "__main__":
    main()
