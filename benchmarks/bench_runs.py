"""Benchmark: the fixed cost of a run, and of each extra run, before and after (issue 16).

The seed-000 loop of ``experiments/seed000_models_abc.toml`` (5 FMUs) is written to a
temporary manifest with ``stop`` = one step (1 ms), so a run is nearly all fixed cost:
process start, imports, FMU extraction, instantiation, one step, the result files. Two
commands do the same work on the same FMUs (this checkout's ``fmus/``):

before
    the ``agv-cosim`` of a baseline environment, named by ``--before PATH`` (required),
    e.g. the code before issue 16: ``git worktree add ../agv-old 14af212 && make -C
    ../agv-old venv``, then ``--before ../agv-old/.venv/bin/agv-cosim``;
after
    this environment's ``agv-cosim``.

Each is timed as a whole process (``agv-cosim run ... --quiet --jobs 1``: serial, so the
extra runs do not hide behind a second core) for 1 run (variant a) and 3 runs (variants
a, b, c), rounds alternating before / after; the medians are printed, the cost of one
extra run ((3 runs - 1 run) / 2) and the ratios before / after.

Run: ``.venv/bin/python benchmarks/bench_runs.py --before PATH [--rounds 5]``
"""

import argparse
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _manifest(folder):
    text = (ROOT / "experiments" / "seed000_models_abc.toml").read_text()
    text = re.sub(r"(?m)^stop = .*$", "stop = 0.001", text)
    text = text.replace('"../fmus/', f'"{ROOT / "fmus"}/')
    path = Path(folder) / "fixed_cost.toml"
    path.write_text(text)
    return path


def _time(command, manifest, variants, out):
    args = [command, "run", str(manifest), "--quiet", "--jobs", "1", "--out", str(out),
            "--overwrite"]
    for variant in variants:
        args += ["--variant", variant]
    begin = time.perf_counter()
    done = subprocess.run(args, capture_output=True, text=True)
    wall = time.perf_counter() - begin
    if done.returncode != 0:
        sys.exit(f"{command} failed ({done.returncode}): {done.stderr.strip()}")
    return wall


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--before", required=True, metavar="PATH",
                        help="agv-cosim command of the baseline environment")
    args = parser.parse_args(argv)
    after = str(Path(sys.executable).with_name("agv-cosim"))
    if not Path(args.before).is_file():
        sys.exit(f"--before: {args.before} not found")
    folder = Path(tempfile.mkdtemp(prefix="bench-runs-"))
    try:
        manifest = _manifest(folder)
        times = {(who, n): [] for who in ("before", "after") for n in (1, 3)}
        for _ in range(args.rounds):
            for who, command in (("before", args.before), ("after", after)):
                for n, variants in ((1, ["a"]), (3, ["a", "b", "c"])):
                    times[(who, n)].append(_time(command, manifest, variants,
                                                 folder / f"out-{who}-{n}"))
        med = {key: statistics.median(value) for key, value in times.items()}
        extra = {who: (med[(who, 3)] - med[(who, 1)]) / 2 for who in ("before", "after")}
        print(f"fixed cost of runs to stop = 1 step, seed-000 loop (5 FMUs), --jobs 1, "
              f"median of {args.rounds} rounds [s]")
        print(f"{'':24}{'before':>10}{'after':>10}{'ratio':>10}")
        for label, b, a in (("1 run", med[("before", 1)], med[("after", 1)]),
                            ("3 runs", med[("before", 3)], med[("after", 3)]),
                            ("each extra run", extra["before"], extra["after"])):
            print(f"{label:24}{b:10.2f}{a:10.2f}{b / a:10.2f}")
        print("min / max per figure:", {f"{w} {n}": (round(min(v), 2), round(max(v), 2))
                                        for (w, n), v in times.items()})
    finally:
        shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
