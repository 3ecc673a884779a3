"""Benchmark: the master against a plain C host stepping the same FMUs (issue 36).

Loops (the shipped manifests, FMUs from ``--fmus``, default the checkout's ``fmus/``,
built by ``agv-cosim build --out fmus``):

seed000
    experiments/seed000_models_abc.toml variant ``a``: 5 FMUs, Gauss-Seidel at 1 ms,
    9 signals recorded every 10th step.
seed003
    the first run of experiments/seed003_speed.toml: the 7-FMU train loop (train, axle
    errors, Ackermann, four fuzzy PDs), Gauss-Seidel at 2 ms.

Sides, each in a fresh child process, interleaved in every repeat:

master
    ``simulate(plan, fast=True)``: what ``agv-cosim run`` does, with the compiled call path
    (agv_cosim/execution/compiled.py) when it is available.
master-ctypes
    the same with ``AGV_COSIM_NO_C=1``: the generated Python functions calling through
    ctypes (the master before the compiled path).
c-host
    benchmarks/c_host_loop.c, compiled here with gcc: dlopen, instantiate, parameters,
    then per macro step every doStep and one Gauss-Seidel pass in the master's order (the
    same reads, sets and read-first units, derived here from the run's plan), statuses
    checked, no NaN check, the same rows recorded.

Each side's figure is its CPU time (``time.process_time`` / CLOCK_PROCESS_CPUTIME_ID)
from its first recorded row to its last, per macro step, so loading and instantiating
are not counted. Every child returns a digest of its rows: they must all be equal
(bit-identical results, and proof that every side did the same work), else the script
exits with status 1. Printed: the median per side and the median over repeats of
master / c-host and master-ctypes / c-host (target <= 1.10).

Run: ``python benchmarks/bench_c_host.py [--loops seed000,seed003] [--repeats 5]
[--stop 10] [--fmus fmus]``.
"""

import argparse
import dataclasses
import hashlib
import json
import os
import shutil
import statistics
import struct
import subprocess
import sys
import tempfile
import time
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parent.parent
HOST_SOURCE = Path(__file__).resolve().parent / "c_host_loop.c"
LOOPS = {"seed000": ("experiments/seed000_models_abc.toml", "a"),
         "seed003": ("experiments/seed003_speed.toml", None)}
SIDES = ("master", "master-ctypes", "c-host")


def load_job(loop: str, stop: float | None, fmus: Path) -> Any:
    """The loop's job, its FMUs taken from ``fmus`` and its stop time ``stop``."""
    from agv_cosim.pipeline import prepare

    manifest, variant = LOOPS[loop]
    text = (ROOT / manifest).read_text().replace('"../fmus/', f'"{fmus.resolve()}/')
    folder = Path(tempfile.mkdtemp(prefix="bench_c_host_"))
    try:
        path = folder / Path(manifest).name
        path.write_text(text)
        jobs = prepare(path)[1]
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    job = next(j for j in jobs if variant is None or j.variant == variant)
    plan = job.plan
    if stop is not None:
        steps = round((stop - plan.start) / plan.step)
        plan = dataclasses.replace(plan, stop=stop, steps=steps)
    return plan


def digest(rows: list[list[float]]) -> str:
    h = hashlib.sha256()
    for row in rows:
        h.update(struct.pack(f"<{len(row)}d", *row))
    return h.hexdigest()[:16]


def run_master(plan: Any) -> dict[str, Any]:
    from agv_cosim.execution import RowObserver, simulate

    rows: list[list[float]] = []
    marks: list[float] = []

    def keep(row: Sequence[Any]) -> None:
        rows.append(list(row))
        marks.append(time.process_time())

    simulate(plan, [RowObserver(keep)], fast=True)
    return {"cpu_us": (marks[-1] - marks[0]) / plan.steps * 1e6, "digest": digest(rows),
            "rows": len(rows)}


def schedule(plan: Any, folder: Path) -> Path:
    """The C host's schedule for ``plan`` (FMUs extracted into ``folder``)."""
    from agv_cosim.execution.grid import Grid

    models = plan.models
    index = {name: i for i, name in enumerate(models)}
    lines = []
    parts = Grid(plan.start, plan.stop, plan.steps, plan.step).exact_parts()
    if parts is None:
        raise SystemExit("the C host needs a grid exact in doubles")
    base, slope, den, step = parts
    lines.append(f"grid {base} {slope} {den} {step.hex()} {plan.steps} "
                 f"{float(plan.start).hex()} {float(plan.stop).hex()} {plan.record_every}")
    connected: dict[str, list[Any]] = {}
    needed: dict[str, set[str]] = {name: set() for name in models}
    for conn in plan.connections:
        connected.setdefault(conn.target[0], []).append(conn)
        needed[conn.source[0]].add(conn.source[1])
    for name in plan.record:
        cname, _, vname = name.partition(".")
        needed[cname].add(vname)
    outs = {name: [v.name for v in info.outputs if v.name in needed[name]]
            for name, info in models.items()}
    for name, info in models.items():
        if info.table is not None or info.fmi_version != "2.0":
            raise SystemExit(f"the C host runs FMI 2.0 FMUs only ({name})")
        unzip = folder / name
        with zipfile.ZipFile(info.path) as archive:
            archive.extractall(unzip)
        lines.append(f"fmu {unzip} {info.identifier} {info.guid} {name}")
        for pname, value in plan.parameters.get(name, {}).items():
            var = info.variables[pname]
            kind = var.ftype.name
            if kind == "Real":
                lines.append(f"param {index[name]} r {var.vr} {float(value).hex()}")
            elif kind in ("Integer", "Enumeration", "Boolean"):
                lines.append(f"param {index[name]} {'b' if kind == 'Boolean' else 'i'} "
                             f"{var.vr} {int(value)}")
            elif kind == "String" and str(value) and not any(c.isspace() for c in str(value)):
                lines.append(f"param {index[name]} s {var.vr} {value}")
            else:
                raise SystemExit(f"the C host cannot set {name}.{pname} = {value!r}")
        for vname in outs[name]:
            if info.variables[vname].ftype.name != "Real":
                raise SystemExit(f"the C host reads Real outputs only ({name}.{vname})")
        vrs = " ".join(str(info.variables[v].vr) for v in outs[name])
        lines.append(f"out {index[name]} {len(outs[name])} {vrs}".rstrip())
        links = []
        for conn in connected.get(name, []):
            var = info.variables[conn.target[1]]
            if var.ftype.name != "Real":
                raise SystemExit(f"the C host sets Real inputs only ({name}.{var.name})")
            src = conn.source[0]
            links.append(f"{var.vr} {index[src]} {outs[src].index(conn.source[1])}")
        lines.append(f"in {index[name]} {len(links)} {' '.join(links)}".rstrip())
    # the master's pass (agv_cosim.execution.algorithm.GaussSeidel)
    position = {name: i for i, name in enumerate(plan.order)}
    backward = {conn.source[0] for conn in plan.connections
                if position[conn.source[0]] >= position[conn.target[0]]}
    for name in plan.order:
        if name in backward:
            once = not any(models[name].dependencies.get(o) for o in outs[name])
            lines.append(f"pre {index[name]} {int(once)}")
    lines += [f"order {index[name]}" for name in plan.order]
    for name in plan.record:
        cname, _, vname = name.partition(".")
        lines.append(f"record {index[cname]} {outs[cname].index(vname)}")
    path = folder / "schedule.txt"
    path.write_text("\n".join(lines) + "\n")
    return path


def run_c_host(host: Path, schedule_file: Path, record: int) -> dict[str, Any]:
    out = schedule_file.with_name("rows.bin")
    env = dict(os.environ, VIRTUAL_ENV=sys.prefix,
               PATH=f"{Path(sys.prefix) / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}")
    done = subprocess.run([str(host), str(schedule_file), str(out)], capture_output=True,
                          text=True, env=env)
    if done.returncode != 0:
        raise SystemExit(f"c host failed: {done.stderr.strip()[-500:]}")
    cpu_us, _ = done.stdout.split()
    data = out.read_bytes()
    width = 8 * (1 + record)
    rows = [list(struct.unpack(f"<{1 + record}d", data[i:i + width]))
            for i in range(0, len(data), width)]
    return {"cpu_us": float(cpu_us), "digest": digest(rows), "rows": len(rows)}


def child(args: argparse.Namespace) -> None:
    plan = load_job(args.loop, args.stop, Path(args.fmus))
    print(json.dumps(run_master(plan)))


def compile_host(folder: Path) -> Path:
    import fmpy

    host = folder / "c_host_loop"
    headers = Path(fmpy.__file__).parent / "c-code"
    subprocess.run(["gcc", "-O2", "-Wall", "-Wextra", f"-I{headers}", "-o", str(host),
                    str(HOST_SOURCE), "-ldl", "-lm"], check=True)
    return host


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--loops", default="seed000,seed003")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--stop", type=float, default=10.0,
                        help="simulated seconds per run (default 10)")
    parser.add_argument("--fmus", default=str(ROOT / "fmus"))
    parser.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--loop", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        child(args)
        return 0
    failed = False
    with tempfile.TemporaryDirectory(prefix="bench_c_host_") as tmp:
        host = compile_host(Path(tmp))
        for loop in args.loops.split(","):
            plan = load_job(loop, args.stop, Path(args.fmus))
            folder = Path(tmp) / loop
            folder.mkdir()
            sched = schedule(plan, folder)
            results: dict[str, list[dict[str, Any]]] = {side: [] for side in SIDES}
            for _ in range(args.repeats):
                for side in SIDES:
                    if side == "c-host":
                        results[side].append(run_c_host(host, sched, len(plan.record)))
                        continue
                    env = dict(os.environ)
                    env.pop("AGV_COSIM_NO_C", None)
                    if side == "master-ctypes":
                        env["AGV_COSIM_NO_C"] = "1"
                    done = subprocess.run(
                        [sys.executable, __file__, "--child", "--loop", loop, "--stop",
                         str(args.stop), "--fmus", args.fmus], capture_output=True,
                        text=True, env=env, check=False)
                    if done.returncode != 0:
                        raise SystemExit(f"{side} failed: {done.stderr.strip()[-800:]}")
                    results[side].append(json.loads(done.stdout.strip().splitlines()[-1]))
            digests = {r["digest"] for side in SIDES for r in results[side]}
            print(f"{loop}: {plan.steps} macro steps, {len(plan.models)} FMUs, "
                  f"{args.repeats} repeats, CPU us per macro step:")
            for side in SIDES:
                cpus = [r["cpu_us"] for r in results[side]]
                print(f"  {side:14s} median {statistics.median(cpus):7.2f}   "
                      + " ".join(f"{c:.2f}" for c in cpus))
            for side in ("master", "master-ctypes"):
                ratios = [m["cpu_us"] / c["cpu_us"]
                          for m, c in zip(results[side], results["c-host"])]
                print(f"  {side} / c-host: median of repeats {statistics.median(ratios):.3f} "
                      f"({' '.join(f'{r:.3f}' for r in ratios)})")
            if len(digests) == 1:
                print(f"  recordings bit-identical on every side (digest {digests.pop()})")
            else:
                print(f"  RECORDINGS DIFFER: {sorted(digests)}")
                failed = True
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
