"""Benchmark: cost of one macro step of the seed-000 loop, old code against new, side by side.

The loop is seed 000 model a, exactly as ``experiments/seed000_models_abc.toml`` variant
``a`` runs it: AgvVehicle (nonlinear, front reference point), AgvSteeringA (K e^(-0.05 s)/s),
AgvVisionSensor (ideal, ``line:``), AgvSteerSensor (ideal) and AgvStateFeedback (eq 10),
Gauss-Seidel at 1 ms, recording the manifest's 9 signals every 10th step (0.01 s).

Two code versions run in the same benchmark:

old
    The tree of git revision ``--old`` (default 14af212, main before issue 16), unpacked
    with ``git archive`` into a temporary folder, its FMUs built by its own build code,
    and run with its own orchestrator (``PYTHONPATH`` puts the old packages first).
new
    This checkout, its FMUs built into a temporary folder.

and each in two ways, every one in a fresh child process:

orchestrator
    ``runner.prepare`` on the manifest, then ``master.simulate`` with a ``write_row`` that
    keeps the rows in memory (no CSV): what a run costs per macro step.
floor
    The same slave classes, loaded in plain Python from the built FMUs' resources (no FMI,
    no ctypes), driven through their attributes and the ``advance`` / ``publish`` hooks in
    the master's Gauss-Seidel order, publishing when that version's adapter does (after
    every step, and after every set of inputs; a ``lazy_publish`` slave of the new
    adapter not after the step): the cores-only floor.

The per-step time is the wall (and CPU) time from the first recorded row to the last,
divided by the number of macro steps, so loading and instantiation are not counted. The
repeats are interleaved (old, new, old floor, new floor, then again), and the script
prints the median of each, the old / new ratio (target >= 2) and each version's ratio to
its floor. Every child also returns a digest of its recording: the four must be equal
(bit-identical results, and proof that every side did the same work), or the script says
so and exits with status 1.

``--callgrind`` counts instructions instead (valgrind's callgrind, one child per kind):
the instrumentation is switched on at the first recorded row and off at the last (a tiny
library compiled here issues callgrind's client requests), so the count is the macro
steps' and nothing else. Instruction counts do not depend on the machine's load, which
the times on a shared machine do; the script prints instructions per macro step and the
same ratios.

Run: ``python benchmarks/bench_step.py [--old 14af212] [--repeats 5] [--stop 10]
[--callgrind]``.
"""

import argparse
import hashlib
import importlib.util
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
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
MANIFEST = "experiments/seed000_models_abc.toml"
VARIANT = "a"
FMU_NAMES = ("AgvVehicle", "AgvSteeringA", "AgvVisionSensor", "AgvSteerSensor",
             "AgvStateFeedback")


# ------------------------------------------------------------------------ set-up
def unpack_old(rev, folder):
    """The tree of ``rev`` in ``folder`` (``git archive``; no worktree is registered)."""
    folder.mkdir(parents=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", rev], check=True,
                             capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(folder)], input=archive, check=True)
    return folder


def env_for(tree):
    """Environment whose ``agv_cosim`` / ``agv_core`` are those of checkout ``tree``."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(tree / "orchestrator"),
                                         str(tree / "components")])
    return env


def build_fmus(tree, out):
    """Build the five FMUs from ``tree``'s sources with ``tree``'s build code.

    ``slave_scripts`` of each tree knows where its slave scripts are (``components/slaves/``
    in the old layout, ``components/agv_core/<component>/agv_*.py`` in the new one).
    """
    stems = ["agv_vehicle", "agv_steering_a", "agv_vision_sensor", "agv_steer_sensor",
             "agv_state_feedback"]
    code = ("import sys\nfrom pathlib import Path\n"
            "from agv_cosim.build import build_one, default_components_dir, slave_scripts\n"
            "scripts = {p.stem: p for p in slave_scripts(default_components_dir())}\n"
            f"for stem in {stems!r}:\n"
            "    build_one(scripts[stem], Path(sys.argv[1]))\n")
    subprocess.run([sys.executable, "-c", code, str(out)], check=True, env=env_for(tree),
                   cwd=str(out.parent))


def write_manifest(tree, folder, stop):
    """The seed-000 manifest of ``tree`` in ``folder/experiments`` (its FMUs in
    ``folder/fmus``), with the stop time replaced."""
    text = (tree / MANIFEST).read_text()
    lines = []
    for line in text.splitlines():
        if line.startswith("stop = "):
            line = f"stop = {stop!r}"
        lines.append(line)
    path = folder / "experiments" / Path(MANIFEST).name
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    return path


# ------------------------------------------------------------------------ children
def _digest(rows):
    h = hashlib.sha256()
    for row in rows:
        h.update(struct.pack(f"<{len(row)}d", *row))
    return h.hexdigest()[:16]


def _plan(manifest):
    try:
        from agv_cosim.pipeline import prepare
    except ImportError:  # a tree before agv_cosim.pipeline (its runner module)
        from agv_cosim.runner import prepare

    _, jobs, _ = prepare(manifest, variants=[VARIANT])
    return jobs[0].plan


def child_orchestrator(manifest, fast=True):
    """Run through the orchestrator's simulate (``fast``: its generated per-step functions,
    else the plain reference loops, where a tree has both); per-step wall and CPU time
    [s], digest."""
    plan = _plan(manifest)
    n_steps = int(round((plan.stop - plan.start) / plan.step))
    rows, stamps = [], []

    def write_row(row):
        rows.append(tuple(row))
        stamps.append((time.perf_counter(), time.process_time()))

    try:
        from agv_cosim.execution import RowObserver, simulate

        simulate(plan, [RowObserver(write_row)], fast=fast)
    except ImportError:  # a tree before agv_cosim.execution (its master module)
        from agv_cosim.master import simulate

        simulate(plan, write_row)
    return {"wall": (stamps[-1][0] - stamps[0][0]) / n_steps,
            "cpu": (stamps[-1][1] - stamps[0][1]) / n_steps, "rows": len(rows),
            "digest": _digest(rows)}


def _load_slave(fmu, name, folder):
    """Instance ``name`` of the slave class inside ``fmu``, loaded in plain Python."""
    from fmpy import read_model_description

    target = folder / name
    with zipfile.ZipFile(fmu) as archive:
        archive.extractall(target)
    resources = target / "resources"
    model = read_model_description(str(fmu)).coSimulation.modelIdentifier
    script = next(p for p in resources.glob("*.py") if p.stem.lower().replace("_", "") ==
                  model.lower())
    sys.path.insert(0, str(resources))
    try:
        spec = importlib.util.spec_from_file_location(script.stem, script)
        module = importlib.util.module_from_spec(spec)
        sys.modules[script.stem] = module
        spec.loader.exec_module(module)
        cls = getattr(module, model)
        return cls(instance_name=name, resources=str(resources))
    finally:
        sys.path.pop(0)


def child_floor(manifest):
    """The slave classes in plain Python: attributes + advance/publish, the master's
    Gauss-Seidel order and record rows; per-step wall and CPU time [s], digest."""
    plan = _plan(manifest)
    folder = Path(tempfile.mkdtemp(prefix="agv_bench_floor_"))
    try:
        slaves = {c: _load_slave(info.path, c, folder) for c, info in plan.models.items()}
        for cname, slave in slaves.items():
            slave.setup_experiment(plan.start)
            for pname, value in plan.parameters.get(cname, {}).items():
                setattr(slave, pname, type(getattr(slave, pname))(value))
            slave.enter_initialization_mode()
            slave.exit_initialization_mode()
        links = {c: [] for c in plan.models}
        for conn in plan.connections:
            links[conn.target[0]].append((conn.target[1], slaves[conn.source[0]],
                                          conn.source[1]))
        order = [(slaves[c], tuple(links[c])) for c in plan.order]
        stepped = list(slaves.values())
        record = [(slaves[n.split(".")[0]], n.split(".")[1]) for n in plan.record]
        n_steps = int(round((plan.stop - plan.start) / plan.step))
        h, every = plan.step, plan.record_every
        rows, stamps = [], []

        # a slave with lazy_publish (new adapter) publishes after a step only at the next
        # read: here, after its sets in the pass
        lazy = {id(s) for s in slaves.values() if getattr(s, "_lazy_step", False)}

        def gs_pass():
            for slave, inputs in order:
                if inputs:
                    for name, src, out in inputs:
                        setattr(slave, name, getattr(src, out))
                    slave.publish()
                elif id(slave) in lazy:
                    slave.publish()

        def record_row(t):
            rows.append((t, *[getattr(s, v) for s, v in record]))
            stamps.append((time.perf_counter(), time.process_time()))

        gs_pass()
        record_row(plan.start)
        for k in range(n_steps):
            t = plan.start + k * h
            for slave in stepped:
                slave.advance(t, h)
                slave.time = t + h
                if id(slave) not in lazy:
                    slave.publish()
            t_next = plan.start + (k + 1) * h
            gs_pass()
            if (k + 1) % every == 0 or k + 1 == n_steps:
                record_row(t_next)
        return {"wall": (stamps[-1][0] - stamps[0][0]) / n_steps,
                "cpu": (stamps[-1][1] - stamps[0][1]) / n_steps, "rows": len(rows),
                "digest": _digest(rows)}
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def run_child(kind, manifest, env):
    out = subprocess.run([sys.executable, __file__, "--child", kind, str(manifest)],
                         check=True, capture_output=True, text=True, env=env,
                         cwd=str(Path(manifest).parent))
    result = json.loads(out.stdout.strip().splitlines()[-1])
    return result


# ------------------------------------------------------------------------ callgrind
CALLGRIND_CONTROL = r"""
#include <valgrind/callgrind.h>
void agv_bench_start(void) { CALLGRIND_ZERO_STATS; CALLGRIND_START_INSTRUMENTATION; }
void agv_bench_stop(void) { CALLGRIND_STOP_INSTRUMENTATION; CALLGRIND_DUMP_STATS; }
"""


def _instrumented_time(library, rows):
    """A stand-in for the ``time`` module whose ``perf_counter`` switches callgrind's
    instrumentation on at the first recorded row and off at row ``rows``."""
    import ctypes

    control = ctypes.CDLL(library)
    real = time  # the module (the caller then rebinds the name ``time`` to Clock)

    class Clock:
        calls = 0

        @staticmethod
        def perf_counter():
            Clock.calls += 1
            if Clock.calls == 1:
                control.agv_bench_start()
            elif Clock.calls == rows:
                control.agv_bench_stop()
            return real.perf_counter()

        process_time = staticmethod(real.process_time)

    return Clock


def run_callgrind(kind, manifest, env, library, stop, folder):
    """Instructions per macro step of one child under callgrind."""
    steps = int(round(stop / 0.001))
    rows = steps // 10 + 1
    out = folder / f"callgrind.{kind}.{abs(hash(str(manifest)))}"
    for old in folder.glob(out.name + "*"):
        old.unlink()
    command = ["valgrind", "--tool=callgrind", "--instr-atstart=no",
               f"--callgrind-out-file={out}", sys.executable, __file__, "--child", kind,
               str(manifest), "--instrument", library, str(rows)]
    subprocess.run(command, check=True, capture_output=True, text=True, env=env,
                   cwd=str(Path(manifest).parent))
    totals = [int(line.split()[1]) for dump in folder.glob(out.name + ".*")
              for line in dump.read_text().splitlines() if line.startswith("totals:")]
    if not totals or max(totals) == 0:
        raise SystemExit(f"callgrind counted nothing for {kind} ({manifest})")
    return max(totals) / steps


# ------------------------------------------------------------------------ main
def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--old", default="14af212", help="git revision of the old code")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--stop", type=float, default=10.0, help="simulated time [s]")
    parser.add_argument("--plain", action="store_true",
                        help="also time this checkout's plain reference loops (fast=False)")
    parser.add_argument("--callgrind", action="store_true",
                        help="count instructions per macro step (valgrind) instead of times")
    parser.add_argument("--child", nargs=2, metavar=("KIND", "MANIFEST"),
                        help=argparse.SUPPRESS)
    parser.add_argument("--instrument", nargs=2, metavar=("LIBRARY", "ROWS"),
                        help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        kind, manifest = args.child
        if args.instrument:
            global time
            time = _instrumented_time(args.instrument[0], int(args.instrument[1]))
        run = {"orchestrator": child_orchestrator, "floor": child_floor,
               "plain": lambda m: child_orchestrator(m, fast=False)}[kind]
        result = run(manifest)
        print(json.dumps(result))
        return 0

    tmp = Path(tempfile.mkdtemp(prefix="agv_bench_step_"))
    try:
        old_tree = unpack_old(args.old, tmp / "old_tree")
        sides = {"old": old_tree, "new": ROOT}
        manifests, envs = {}, {}
        for side, tree in sides.items():
            folder = tmp / side
            (folder / "fmus").mkdir(parents=True)
            build_fmus(tree, folder / "fmus")
            manifests[side] = write_manifest(tree, folder, args.stop)
            envs[side] = env_for(tree)
        keys = [("old", "orchestrator"), ("new", "orchestrator"), ("old", "floor"),
                ("new", "floor")]
        if args.plain:  # this checkout's reference loops beside its fast path
            keys.append(("new", "plain"))
        if args.callgrind:
            library = tmp / "callgrind_control.so"
            (tmp / "callgrind_control.c").write_text(CALLGRIND_CONTROL)
            subprocess.run(["gcc", "-shared", "-fPIC", "-O2", "-o", str(library),
                            str(tmp / "callgrind_control.c")], check=True)
            counts = {key: run_callgrind(key[1], manifests[key[0]], envs[key[0]],
                                         str(library), args.stop, tmp) for key in keys}
            print(f"seed-000 model a, instructions per macro step (callgrind), "
                  f"{args.stop:g} s simulated; old = {args.old}, new = this checkout")
            for key in keys:
                print(f"  {key[0]:3s} {key[1]:12s} {counts[key]:10.0f}")
            for side in ("old", "new"):
                print(f"{side} orchestrator / {side} floor: "
                      f"{counts[(side, 'orchestrator')] / counts[(side, 'floor')]:.3f}")
            print(f"old / new orchestrator: "
                  f"{counts[('old', 'orchestrator')] / counts[('new', 'orchestrator')]:.2f}x")
            return 0
        results = {key: [] for key in keys}
        print(f"seed-000 model a, 1 ms, record every 10th step, {args.stop:g} s simulated "
              f"= {int(round(args.stop / 0.001))} steps; old = {args.old}, new = this "
              f"checkout; {args.repeats} interleaved repeats")
        for r in range(args.repeats):
            for side, kind in keys:
                res = run_child(kind, manifests[side], envs[side])
                results[(side, kind)].append(res)
                print(f"  repeat {r + 1}: {side:3s} {kind:12s} {res['wall'] * 1e6:7.1f} us/step "
                      f"wall, {res['cpu'] * 1e6:7.1f} CPU  [{res['digest']}]", flush=True)
        med = {key: (statistics.median(r["wall"] for r in rs) * 1e6,
                     statistics.median(r["cpu"] for r in rs) * 1e6)
               for key, rs in results.items()}
        print("\nmedians (us per macro step):        wall      CPU")
        for key in keys:
            print(f"  {key[0]:3s} {key[1]:28s} {med[key][0]:7.1f}  {med[key][1]:7.1f}")
        # ratio pair by pair (the same repeat), then the median: robust to drift
        pair = [o["wall"] / n["wall"] for o, n in zip(results[("old", "orchestrator")],
                                                      results[("new", "orchestrator")])]
        pair_cpu = [o["cpu"] / n["cpu"] for o, n in zip(results[("old", "orchestrator")],
                                                        results[("new", "orchestrator")])]
        if ("new", "plain") in results:
            plain = [p["wall"] / n["wall"] for p, n in zip(results[("new", "plain")],
                                                         results[("new", "orchestrator")])]
            plain_cpu = [p["cpu"] / n["cpu"] for p, n in zip(results[("new", "plain")],
                                                           results[("new", "orchestrator")])]
            print(f"\nnew plain loops / new fast path, median of pairs: wall "
                  f"{statistics.median(plain):.2f}, CPU {statistics.median(plain_cpu):.2f}")
        print(f"\nspeed-up old / new (orchestrator), median of pairs: wall "
              f"{statistics.median(pair):.2f}x, CPU {statistics.median(pair_cpu):.2f}x "
              f"(target >= 2)")
        for side in ("old", "new"):
            print(f"{side} orchestrator / {side} floor: wall "
                  f"{med[(side, 'orchestrator')][0] / med[(side, 'floor')][0]:.2f}, CPU "
                  f"{med[(side, 'orchestrator')][1] / med[(side, 'floor')][1]:.2f}")
        print(f"new orchestrator / old floor: wall "
              f"{med[('new', 'orchestrator')][0] / med[('old', 'floor')][0]:.2f}")
        digests = {r["digest"] for rs in results.values() for r in rs}
        if len(digests) != 1:
            print(f"\nRECORDINGS DIFFER: {sorted(digests)}")
            return 1
        print(f"\nall {sum(len(rs) for rs in results.values())} recordings bit-identical "
              f"(digest {digests.pop()})")
        return 0
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
