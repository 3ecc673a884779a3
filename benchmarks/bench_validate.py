"""Benchmark: how ``agv-cosim validate`` grows with the number of components.

A manifest of N components is generated: a ramp source feeding N - 1 gains (the test
FMUs of ``tests/fmu_src``, built into a temporary folder), half of them directly, the
other half each through the gain before it (so the schedule has many components ready
at once, and chains); every component has a parameter set. The command
is timed as a whole process, for N = 1000 and 3000 (``--sizes``):

- ``validate --no-init``: reading, planning and checking the manifest against the
  model descriptions and finding the Gauss-Seidel order (what grew quadratically:
  ``feedthrough_order`` sorted its ready list with ``list.index`` at every step);
- ``validate`` (``--init`` adds it): the same, then the initialisation check, which
  instantiates and initialises each distinct (FMU, parameter values) pair once in a
  child process: timed with every gain's ``k`` the same (two pairs whatever N) and
  with every ``k`` different (N pairs: it grows with N by the FMU's own cost).

The time per component of each size is printed, and the ratio of the largest size's
time per component to the smallest's (1.0: linear).

``--command`` times another ``agv-cosim`` (e.g. a checkout before the change, as
``env PYTHONPATH=../old/orchestrator:../old/components .venv/bin/python -m
agv_cosim.cli``) instead of this environment's.

Run: ``.venv/bin/python benchmarks/bench_validate.py [--sizes 1000 3000] [--init]
[--command CMD]``
"""

import argparse
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
AGV_COSIM = Path(sys.executable).with_name("agv-cosim")


def _build(folder):
    from agv_cosim.build import build_one

    src = ROOT / "tests" / "fmu_src"
    return {name: build_one(src / f"{name}.py", folder).fmu
            for name in ("agv_test_source", "agv_test_gain")}


def manifest(folder, fmus, n, distinct=True):
    """``n`` components: src -> g(odd i); g(i - 1) -> g(even i); each gain's ``k``
    its own (``distinct``) or all the same."""
    lines = [f'name = "chain{n}"', "[simulation]", "stop = 1.0", "step = 0.1",
             "[components.src]", f'fmu = "{fmus["agv_test_source"]}"',
             "parameters = { offset = 1.0, slope = 2.0 }"]
    for i in range(1, n):
        lines += [f"[components.g{i}]", f'fmu = "{fmus["agv_test_gain"]}"',
                  f"parameters = {{ k = {1.0 + i * 1e-6 if distinct else 2.0!r} }}"]
    for i in range(1, n):
        source = "src" if i % 2 else f"g{i - 1}"
        lines += ["[[connections]]", f'from = "{source}.y"', f'to = "g{i}.u"']
    lines += ["[record]", f'variables = ["g{n - 1}.y"]']
    path = Path(folder) / f"chain{n}{'' if distinct else '_same'}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def _time(command, args):
    begin = time.perf_counter()
    done = subprocess.run([*command, *args], capture_output=True, text=True)
    wall = time.perf_counter() - begin
    if done.returncode != 0:
        sys.exit(f"agv-cosim {' '.join(args)} failed ({done.returncode}): "
                 f"{done.stderr.strip()}")
    return wall


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 3000])
    parser.add_argument("--init", action="store_true",
                        help="also time validate with the initialisation check")
    parser.add_argument("--command", default=str(AGV_COSIM),
                        help="the agv-cosim command to time (default: this environment's)")
    args = parser.parse_args(argv)
    command = shlex.split(args.command)
    with tempfile.TemporaryDirectory(prefix="bench_validate_") as tmp:
        fmus = _build(Path(tmp))
        kinds = [("validate --no-init", ["--no-init"], True)]
        if args.init:
            kinds += [("validate, k the same", [], False),
                      ("validate, k distinct", [], True)]
        for title, extra, distinct in kinds:
            per = {}
            for n in args.sizes:
                path = manifest(tmp, fmus, n, distinct)
                wall = _time(command, ["validate", str(path), *extra])
                per[n] = wall / n
                print(f"{title:<22} {n:>6} components: {wall:8.2f} s "
                      f"({per[n] * 1e3:.2f} ms per component)")
            small, large = min(per), max(per)
            if small != large:
                print(f"{title:<22} time per component, {large} / {small}: "
                      f"{per[large] / per[small]:.2f}")


if __name__ == "__main__":
    main()
