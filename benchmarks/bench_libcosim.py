"""Benchmark: libcosim (libcosimpy) stepping our FMUs, built by two code versions.

libcosim steps the FMUs of an SSP package from its worker threads, which Python does not
know: what each FMI call costs in our FMU bridge on such a thread is what this measures.
The package is seed 000 model a (``experiments/seed000_models_abc.toml``, variant a, 5
FMUs, 1 ms), written by this checkout's ``agv_cosim.ssp.exporter.export_ssp`` (what
``agv-cosim export-ssp`` runs) twice, from the FMUs of two builds:

before
    The tree of git revision ``--before`` (default ``main``), unpacked with
    ``git archive`` into a temporary folder, its FMUs built by its own build code.
after
    This checkout's FMUs.

(``--before-fmus DIR`` / ``--after-fmus DIR`` take FMUs built earlier with
``agv-cosim build --out DIR`` instead.) Every measurement runs in a fresh child process
that loads a package with ``CosimExecution.from_ssp_file``, takes the first step
(initialisation) untimed, then times ``execution.step(n)``: the process's CPU time (all
threads) and the wall time, divided by n. Rounds alternate before / after; the script
prints the medians, the CPU saving after / before (target: at least 40 % cheaper), and
checks that both builds end with the same values of every Real output of every FMU, bit
for bit (else it says so and exits with status 1).

Run: ``python benchmarks/bench_libcosim.py [--before main] [--rounds 5] [--stop 5]``.
"""

import argparse
import hashlib
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MANIFEST = "experiments/seed000_models_abc.toml"


def build_fmus(tree, out):
    """``agv-cosim build --out OUT`` with the code of ``tree``."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        [str(Path(tree) / "orchestrator"), str(Path(tree) / "components")]))
    subprocess.run([sys.executable, "-m", "agv_cosim.cli", "build", "--out", str(out)],
                   check=True, env=env, cwd=tree, capture_output=True)
    return out


def make_package(fmus, folder, stop):
    """The seed-000 model-a package over the FMUs in ``fmus``."""
    from agv_cosim.ssp.exporter import export_ssp

    folder.mkdir(parents=True, exist_ok=True)
    text = (ROOT / MANIFEST).read_text()
    text = re.sub(r'"\.\./fmus/(\w+)\.fmu"', lambda m: f'"{Path(fmus) / m.group(1)}.fmu"',
                  text)
    text = re.sub(r"(?m)^stop = [0-9.]+", f"stop = {float(stop)!r}", text)
    manifest = folder / "loop.toml"
    manifest.write_text(text)
    return export_ssp(manifest, folder / "loop.ssp", variant="a")


def child(package, step, n):
    """Time n macro steps of libcosim on ``package``; print a JSON line."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level
    from libcosimpy.CosimObserver import CosimObserver

    log_output_level(CosimLogLevel.WARNING)
    execution = CosimExecution.from_ssp_file(str(package), step_size=int(round(step * 1e9)))
    observer = CosimObserver.create_last_value()
    execution.add_observer(observer)
    assert execution.step(1)  # initialisation happens on the first step; not timed
    cpu, wall = time.process_time(), time.perf_counter()
    assert execution.step(n)
    cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
    digest, count = hashlib.sha256(), 0
    for info in sorted(execution.slave_infos(), key=lambda s: s.name):
        index = execution.slave_index_from_instance_name(info.name.decode())
        refs = sorted(v.reference for v in execution.slave_variables(index)
                      if v.type == 0 and v.causality == 2)  # Real outputs
        values = observer.last_real_values(index, refs)
        count += len(refs)
        digest.update(info.name + repr([float(x) for x in values]).encode())
    print(json.dumps({"cpu": cpu / n, "wall": wall / n, "digest": digest.hexdigest(),
                      "outputs": count}))


def measure(package, step, n):
    done = subprocess.run([sys.executable, __file__, "--child", str(package), repr(step),
                           str(n)], capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"child failed on {package}: {done.stderr.strip()[-2000:]}")
    return json.loads(done.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--before", default="main", help="git revision of the old code")
    parser.add_argument("--before-fmus", type=Path, help="FMUs of the old code (a folder)")
    parser.add_argument("--after-fmus", type=Path, help="FMUs of this checkout (a folder)")
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--stop", type=float, default=5.0, help="simulated time [s]")
    parser.add_argument("--child", nargs=3, metavar=("PACKAGE", "STEP", "N"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args.child[0], float(args.child[1]), int(args.child[2]))
        return 0
    with tempfile.TemporaryDirectory(prefix="bench_libcosim_") as tmp:
        tmp = Path(tmp)
        before_fmus, after_fmus = args.before_fmus, args.after_fmus
        if before_fmus is None:
            tree = tmp / "before-tree"
            tree.mkdir()
            archive = subprocess.run(["git", "-C", str(ROOT), "archive", args.before],
                                     check=True, capture_output=True).stdout
            subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
            before_fmus = build_fmus(tree, tmp / "before-fmus")
        if after_fmus is None:
            after_fmus = build_fmus(ROOT, tmp / "after-fmus")
        packages = {"before": make_package(before_fmus, tmp / "before", args.stop),
                    "after": make_package(after_fmus, tmp / "after", args.stop)}
        step = 0.001
        n = int(round(args.stop / step)) - 1
        results = {"before": [], "after": []}
        for _ in range(args.rounds):
            for kind in ("before", "after"):
                results[kind].append(measure(packages[kind], step, n))
        print(f"libcosim, seed 000 model a (5 FMUs, 1 ms), {n} macro steps timed, "
              f"{args.rounds} rounds interleaved; median per macro step:")
        cpu = {}
        for kind in ("before", "after"):
            cpu[kind] = statistics.median(r["cpu"] for r in results[kind])
            wall = statistics.median(r["wall"] for r in results[kind])
            print(f"  {kind:6s}  CPU {cpu[kind] * 1e6:8.1f} us   wall {wall * 1e6:8.1f} us")
        print(f"  CPU after / before: {cpu['after'] / cpu['before']:.3f} "
              f"({(1 - cpu['after'] / cpu['before']) * 100:.1f} % cheaper; target >= 40 %)")
        digests = {r["digest"] for kind in results for r in results[kind]}
        if len(digests) != 1:
            print(f"  final outputs DIFFER between runs: {sorted(digests)}")
            return 1
        print(f"  final values of the {results['after'][0]['outputs']} Real outputs of the "
              "FMUs: bit-identical in every run")
    return 0


if __name__ == "__main__":
    sys.exit(main())
