"""Time to read one FMU's model description: the ElementTree parser model.py had before
issue 15 (taken from git, commit given with --before) against fmpy.read_model_description
as model.py now uses it. Each read is uncached (the cache is cleared); it happens once per
FMU per run. Prints old/new milliseconds per FMU and the ratio.

    .venv/bin/python benchmarks/bench_model_read.py [--before d7e194d] [--rounds 20] [fmus]
"""

import argparse
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from agv_cosim.system import model as new_model

ROOT = Path(__file__).resolve().parents[1]


def _old_module(commit):
    """model.py as of ``commit``, imported as agv_cosim._model_before (same package)."""
    text = subprocess.run(["git", "-C", str(ROOT), "show", f"{commit}:orchestrator/agv_cosim/"
                           "model.py"], check=True, capture_output=True, text=True).stdout
    folder = Path(tempfile.mkdtemp())
    (folder / "_model_before.py").write_text(text)
    spec = importlib.util.spec_from_file_location("agv_cosim._model_before",
                                                  folder / "_model_before.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def _time(module, path, rounds):
    times = []
    for _ in range(rounds):
        module._CACHE.clear()
        start = time.perf_counter()
        module.read_model(path)
        times.append(time.perf_counter() - start)
    return statistics.median(times) * 1e3


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fmus", nargs="*", type=Path)
    parser.add_argument("--before", default="d7e194d")
    parser.add_argument("--rounds", type=int, default=20)
    args = parser.parse_args()
    fmus = args.fmus or sorted((ROOT / "fmus").glob("*.fmu"))
    old_model = _old_module(args.before)
    print(f"{'FMU':<28}{'old ms':>9}{'new ms':>9}{'new/old':>9}")
    total_old = total_new = 0.0
    for path in fmus:
        before, after = _time(old_model, path, args.rounds), _time(new_model, path, args.rounds)
        total_old, total_new = total_old + before, total_new + after
        print(f"{path.name:<28}{before:9.2f}{after:9.2f}{after / before:9.2f}")
    print(f"{'all (' + str(len(fmus)) + ')':<28}{total_old:9.2f}{total_new:9.2f}"
          f"{total_new / total_old:9.2f}")


if __name__ == "__main__":
    main()
