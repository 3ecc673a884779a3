"""The ``agv-cosim`` command line.

Exit codes: 0 success; 1 a run that failed, is partial or timed out, a metrics error, a
failed build, a cluster that went away or an error of the system (disk full, a result
folder removed during the run, ...); 2 bad input (one line
``agv-cosim: error: <manifest>: <key>: <problem>`` on stderr; also an output folder that
is not ours, or one another run is writing); 128 + N when ended by signal N (SIGINT,
SIGTERM, SIGHUP): the runs already complete are kept in the result folder, marked
partial (``partial.txt``, and each run's status in summary.csv). Every error is one line
on stderr, its control characters escaped (an FMU's message cannot drive the terminal);
``--debug`` adds the traceback and changes nothing else (not the exit code).
"""

import argparse
import atexit
import os
import sys
import traceback
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from .errors import error_lines, exit_code, kept_summary
from .files import printable
from .version import __version__

if TYPE_CHECKING:
    from .build import BuildResult
    from .manifest import Manifest


def _say(text: str) -> None:
    """One line on stderr, control characters escaped."""
    print(printable(text), file=sys.stderr)


def _error(text: str) -> int:
    _say(f"agv-cosim: error: {text}")
    return 2


def _cmd_build(args: argparse.Namespace) -> int:
    from .build import build_fmus, component_scripts
    from .errors import BuildError

    scripts = component_scripts(args.names) if args.names else None
    started = [0.0]

    def progress(k: int, n: int, script: Path, result: "BuildResult | None") -> None:
        import time

        if result is None:
            started[0] = time.monotonic()
            _say(f"agv-cosim build: [{k}/{n}] {script.name} ...")
            return
        state = "built" if result.rebuilt else "up to date"
        print(f"{result.fmu}  {state} ({time.monotonic() - started[0]:.1f} s)", flush=True)

    try:
        build_fmus(args.out, scripts, force=args.force, fmi_version=args.fmi,
                   standalone=args.standalone, progress=progress)
    except BuildError as error:
        print(f"agv-cosim build: error: {error}", file=sys.stderr)
        return 1
    return 0


def _cmd_examples(args: argparse.Namespace) -> int:
    from .build.examples import copy_examples
    from .errors import ExamplesError

    try:
        written = copy_examples(args.folder, args.fmus)
    except ExamplesError as error:
        return _error(str(error))
    for path in written:
        print(path)
    print(f"{len(written)} file(s) in {args.folder}; their FMUs: {args.fmus}/ (build them "
          f"with: agv-cosim build --out {args.fmus})")
    return 0


def _warn(warnings: list[str], quiet: bool = False) -> None:
    """The manifest's warnings on stderr (none with ``quiet``: ``run --quiet``)."""
    if quiet:
        return
    for warning in warnings:
        _say(f"agv-cosim: warning: {warning}")


def _positive(what: str, unit: str = "") -> Callable[[str], float]:
    """An argparse type: a positive, finite number (``what``: "factor", "number of Hz");
    ``unit`` follows "is not a number" in the refusal."""
    import math

    def convert(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number{unit}") from None
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"{text!r} must be a positive, finite {what}")
        return value

    return convert


def _timeout(text: str) -> float:
    """``--timeout``: a positive, finite number of seconds."""
    import math

    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive, finite number of "
                                         "seconds")
    return value


def _worker_options(command: argparse.ArgumentParser, timeout: str | None = None) -> None:
    """The options of a command whose runs go through the workers (run, tune, fit):
    ``--overwrite``, ``--jobs``, ``--dask``, and ``--timeout`` when ``timeout`` is given
    (what becomes of a run over the limit in this command)."""
    command.add_argument("--overwrite", action="store_true",
                         help="replace DIR even if it is not a result folder of agv-cosim "
                              "(without it such a folder is refused)")
    command.add_argument("--jobs", type=int, metavar="N",
                         help="runs at once, in worker processes (a worker is replaced "
                              "after a run that did not complete; default: one per core)")
    command.add_argument("--dask", metavar="ADDRESS",
                         help="run on the Dask cluster whose scheduler is at ADDRESS "
                              "(tcp://HOST:PORT; see docs/dask.md); default: local "
                              "processes")
    if timeout is not None:
        command.add_argument("--timeout", type=_timeout, metavar="SECONDS",
                             help=f"wall-clock limit of each run: {timeout} (default: the "
                                  "manifest's [simulation] timeout, else no limit)")


def _cmd_validate(args: argparse.Namespace) -> int:
    from .pipeline import check_initialisation, prepare

    manifest, jobs, warnings = prepare(args.manifest, args.variant, args.set)
    _warn(warnings)
    if not args.no_init:
        check_initialisation(manifest, jobs, args.timeout)
    print(printable(f"{manifest.path}: ok: {len(jobs)} run(s), "
                    f"{_counts(len(job.plan.models) for job in jobs)} component(s), "
                    f"{_counts(len(job.plan.connections) for job in jobs)} connection(s), "
                    f"{manifest.algorithm}"))
    return 0


def _counts(counts: Iterable[int]) -> str:
    """'5', or '5-7' when the runs (of variants that rewire) have different counts."""
    values = sorted(set(counts))
    if len(values) <= 1:
        return str(values[0] if values else 0)
    return f"{values[0]}-{values[-1]}"



def _cmd_run(args: argparse.Namespace) -> int:
    from .pipeline import check_options, execute, prepare

    if args.jobs is not None and args.jobs < 1:
        return _error("--jobs: must be >= 1")
    manifest, jobs, warnings = prepare(args.manifest, args.variant, args.set,
                                       timeout=args.timeout)
    _warn(warnings, args.quiet)
    check_options(jobs, args.overwrite, args.dask, args.resume, args.real_time)
    from .errors import ClusterError

    try:
        target, results = execute(manifest, jobs, args.out, args.jobs, args.quiet,
                                  overwrite=args.overwrite, dask=args.dask,
                                  resume=args.resume, real_time=args.real_time,
                                  init_limit=_init_limit(args, manifest),
                                  check_step=args.check_step)
    except ClusterError as error:
        _say(f"agv-cosim: error: {error_lines(error)[0]}")
        return exit_code(error)
    bad = [r for r in results if r["status"] != "complete"]
    for result in bad:
        _say(f"agv-cosim: run {result['label']} {result['status']}: {result['error']}")
    unmeasured = [r for r in results if r.get("metrics_error")]
    for result in unmeasured:
        _say(f"agv-cosim: run {result['label']}: metrics: {result['metrics_error']}")
    if not args.quiet:
        import shutil

        from .report import terminal_summary

        columns = shutil.get_terminal_size((120, 24)).columns  # 120 when not a terminal
        table = terminal_summary(target, width=columns)
        if table:
            print(table)
        print(printable(f"{target}: {len(results) - len(bad)}/{len(results)} run(s) "
                        "complete"))
    for result in results:
        if "real_time" in result and not result.get("reused"):
            print(_paced(result["real_time"]))
    return 1 if bad or unmeasured else 0


def _init_limit(args: argparse.Namespace, manifest: "Manifest") -> float | None:
    """The initialisation check's limit per FMU [s] of ``run`` (None: no check, with
    --no-init or --dask). The runs' wall-clock limit bounds a run, not this check: at
    least validate's default."""
    if args.no_init or args.dask is not None:
        return None
    from .pipeline import INIT_TIMEOUT

    return max(args.timeout or manifest.timeout or 0.0, INIT_TIMEOUT)


def _paced(report: Mapping[str, Any]) -> str:
    """One line on a paced run: target and achieved factor, overruns, max lateness."""
    achieved = report["achieved"]
    return (f"real time: target x{report['target']:g}, achieved "
            + ("-" if achieved is None else f"x{achieved:.5g}")
            + f" over {report['steps']} step(s); {report['overruns']} overrun(s), max "
              f"lateness {report['max_lateness_s'] * 1000:.3g} ms")


def _cmd_report(args: argparse.Namespace) -> int:
    from .report import write_report

    page = write_report(args.folder)
    print(printable(str(page)))
    return 0


def _cmd_export_ssp(args: argparse.Namespace) -> int:
    from .ssp import export_ssp

    out = export_ssp(args.manifest, args.output, args.variant, args.set)
    print(printable(str(out)))
    return 0


def _cmd_list(args: argparse.Namespace) -> int:
    from pathlib import Path

    from .errors import ModelError
    from .system.model import describe, find_fmus, read_model

    path = Path(args.path)
    if not path.exists():
        return _error(f"{path}: not found")
    fmus = find_fmus(path)
    if not fmus:
        return _error(f"{path}: no *.fmu files")
    status = 0
    for i, fmu in enumerate(fmus):
        try:
            info = read_model(fmu)
        except ModelError as error:
            _say(f"agv-cosim: error: {fmu}: {error}")
            status = 2
            continue
        if i:
            print()
        print("\n".join(printable(line) for line in describe(info).split("\n")))
    return status


class _Parser(argparse.ArgumentParser):
    """The top-level parser: arguments left over after a subcommand's are that
    subcommand's error (its usage line, not the top-level one)."""

    commands: dict[str, argparse.ArgumentParser] = {}

    # one signature for argparse's overloads (no caller gives its own namespace class)
    def parse_args(self, args: Iterable[str] | None = None,  # type: ignore[override]
                   namespace: argparse.Namespace | None = None) -> argparse.Namespace:
        parsed, extra = self.parse_known_args(args, namespace)
        if extra:
            command = self.commands.get(getattr(parsed, "command", None) or "", self)
            command.error(f"unrecognized arguments: {' '.join(extra)}")
        return parsed


def _plain(text: str | None) -> str:
    """A docstring as ``--help`` shows it: reST's double backquotes as single ones."""
    return (text or "").replace("``", "`")


def _cmd_identify(args: argparse.Namespace) -> int:
    import time

    from .errors import IdentifyError
    from .identification import identify_file

    start = time.perf_counter()
    try:
        found = identify_file(args.data, args.input, args.output, time=args.time,
                              models=args.models, cutoff=args.cutoff, order=args.order,
                              out=args.out, overwrite=args.overwrite)
    except IdentifyError as error:
        return _error(str(error))
    for model, entry in found.result.items():
        parts = []
        for name, p in entry["parameters"].items():
            if p["value"] is None:
                parts.append(f"{name} not identified ({p['reason']})")
            elif p["stderr"] is None:
                parts.append(f"{name} = {p['value']:.6g} ({p.get('reason', '')})")
            else:
                parts.append(f"{name} = {p['value']:.6g} +- {p['stderr']:.2g}")
        print(printable(f"model {model}: fit {entry['fit_percent']:.2f} %: "
                        + "; ".join(parts)))
    print(printable(f"{found.folder}: identified.json, identify.png, "
                    f"identified_variants.toml, index.html "
                    f"({time.perf_counter() - start:.1f} s)"))
    return 0


def _cmd_tune(args: argparse.Namespace) -> int:
    import math
    import time

    from .errors import ClusterError, TuneError
    from .tuning import tune_manifest

    if args.jobs is not None and args.jobs < 1:
        return _error("--jobs: must be >= 1")
    start = time.perf_counter()
    try:
        found = tune_manifest(args.manifest, args.out, workers=args.jobs, dask=args.dask,
                              overwrite=args.overwrite, quiet=args.quiet,
                              timeout=args.timeout)
    except TuneError as error:
        return _error(str(error))
    except ClusterError as error:
        _say(f"agv-cosim: error: {error_lines(error)[0]}")
        return exit_code(error)
    result = found.result

    def shown(value: float) -> str:
        return f"{value:.6g}" if math.isfinite(value) else "infeasible"

    if found.failures:
        trials = len({f["trial"] for f in found.failures})
        _say(f"agv-cosim tune: {len(found.failures)} run(s) of {trials} candidate(s) "
             "failed during the search: those candidates were infeasible and the "
             f"search went on (tune.json: failed_runs; first: trial "
             f"{found.failures[0]['trial']}, run {found.failures[0]['run']}: "
             f"{found.failures[0]['status']}: {found.failures[0]['error']})")
    for name, value in result.best.items():
        print(printable(f"{name}: {result.start[name]!r} -> {value!r}"))
    print(printable(f"objective ({result.objective.aggregate} over "
                    f"{len(result.best_runs)} run(s)): {shown(result.start_value)} -> "
                    f"{shown(result.best_value)} after {result.evaluations} candidate(s)"))
    print(printable(f"{found.folder}: tune.json, tuned_variant.toml, index.html "
                    f"({time.perf_counter() - start:.1f} s)"))
    bad = [job.label for job, r in found.original + found.tuned
           if r["status"] != "complete"]
    return 1 if bad or not math.isfinite(result.best_value) else 0


def _cmd_fit(args: argparse.Namespace) -> int:
    import time

    from .errors import AgvCosimError, ClusterError
    from .manifest_fit import fit_manifest, setup

    if args.jobs is not None and args.jobs < 1:
        return _error("--jobs: must be >= 1")
    if args.max_evaluations is not None and args.max_evaluations < 1:
        return _error("--max-evaluations: must be >= 1")
    start = time.perf_counter()
    try:
        checked = setup(args.manifest, args.variant)
        _warn(checked.warnings)
        found = fit_manifest(args.manifest, args.out, jobs=args.jobs, dask=args.dask,
                             overwrite=args.overwrite, max_evaluations=args.max_evaluations,
                             checked=checked)
    except AgvCosimError as error:
        return _report(args, f"error: {error}", error.exit_code)
    except ClusterError as error:  # the cluster cannot be reached, or went away
        return _report(args, f"error: {error_lines(error)[0]}", exit_code(error))
    result = found.result
    for name in result.names:
        stderr = result.stderr[name]
        shown = (f"{result.values[name]:.6g} +- {stderr:.2g}" if stderr is not None else
                 f"{result.values[name]:.6g} ({result.reasons.get(name, '')})")
        print(printable(f"{name} = {shown}"))
    print(printable(f"{found.folder}: fit.json, fit_variant.toml, fit.png, index.html: "
                    f"{result.iterations} iteration(s), {found.runs} run(s), cost "
                    f"{result.cost:.6g} ({time.perf_counter() - start:.1f} s)"))
    return 0


def make_parser() -> argparse.ArgumentParser:
    """The argument parser of ``agv-cosim`` with all its subcommands."""
    parser = _Parser(prog="agv-cosim", description=_plain(__doc__),
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"agv-cosim {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    debug = argparse.ArgumentParser(add_help=False)
    debug.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                       help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True,
                                parser_class=argparse.ArgumentParser)

    build = sub.add_parser("build", help="build the component FMUs (only what changed)",
                           parents=[debug])
    build.add_argument("names", nargs="*", metavar="NAME",
                       help="build only these components (AgvVehicle or agv_vehicle; "
                            "default: all)")
    build.add_argument("--out", default="fmus", help="output folder (default: fmus)")
    build.add_argument("--force", action="store_true", help="rebuild every FMU")
    build.add_argument("--fmi", type=int, choices=(2, 3), default=2,
                       help="FMI version of the FMUs: 2 (default) or 3 (the FMI 3.0 twins, "
                            "built with pythonfmu3)")
    build.add_argument("--standalone", action="store_true",
                       help="FMUs that carry their own Python runtime and packages (run "
                            "on a Linux x86-64 machine without Python; tens of MB each)")
    build.set_defaults(func=_cmd_build)

    examples = sub.add_parser(
        "examples", help="copy the shipped experiment manifests into a folder",
        parents=[debug],
        description="Copy the shipped experiment manifests (and any file they refer to) "
                    "into FOLDER, their FMU paths pointing at the FMUs 'agv-cosim build' "
                    "writes. A file in FOLDER that this command did not write is never "
                    "replaced (exit 2, nothing copied).")
    examples.add_argument("folder", metavar="FOLDER", help="where to put the manifests")
    examples.add_argument("--fmus", default="fmus", metavar="FMUS",
                          help="folder of the FMUs the manifests use, relative to the "
                               "current folder (default: fmus, where 'agv-cosim build' "
                               "writes; with 'agv-cosim build --out X' give --fmus X)")
    examples.set_defaults(func=_cmd_examples)

    selection = argparse.ArgumentParser(add_help=False)
    selection.add_argument("manifest", help="experiment manifest (TOML)")
    selection.add_argument("--variant", action="append", metavar="NAME",
                           help="run only this variant (repeatable; default: all)")
    selection.add_argument("--set", action="append", default=[], metavar="COMP.PARAM=VALUE",
                           help="override a parameter in every run (VALUE is a TOML value; "
                                "repeatable)")

    run = sub.add_parser("run", help="validate and run a manifest, write results",
                         parents=[selection, debug],
                         description="Run every variant x sweep point of a manifest and "
                                     "write DIR/<run>/{timeseries.csv,metrics.json,run.json}, "
                                     "DIR/summary.csv, plots, index.html and "
                                     "DIR/timings.csv (the wall times: the only file "
                                     "that differs between two runs of a manifest). "
                                     "Exit 0 if all runs are "
                                     "complete, 1 if any failed or is partial, 2 on bad "
                                     "input.",
                         epilog="Monte Carlo: with a [montecarlo] table (samples, seed, "
                                "design random/sobol/lhs, parameters drawn from normal, "
                                "uniform, truncnormal or choice distributions, derived "
                                "seeds) each variant runs once per sample, and "
                                "DIR/montecarlo.json and its figures summarise the "
                                "metrics over the samples. Every key of a manifest: "
                                "docs/manifest.md.")
    run.add_argument("--out", metavar="DIR",
                     help="output folder (default: results/<manifest name>)")
    run.add_argument("--quiet", action="store_true",
                     help="print only errors, the runs that failed and a paced run's "
                          "real-time line: no warnings (e.g. unconnected inputs), "
                          "progress bars, metrics table or summary line")
    _worker_options(run, timeout="a run still going then is stopped and reported 'timed "
                                 "out', the others go on")
    run.add_argument("--no-init", action="store_true",
                     help="skip the check made before any run is written: each FMU "
                          "instantiated and initialised once with each run's parameters, "
                          "as validate does (skipped with --dask: the FMUs run on the "
                          "cluster's machines)")
    run.add_argument("--resume", action="store_true",
                     help="DIR is a result folder of an earlier run of this manifest "
                          "(complete, interrupted or with failed runs): keep each of its "
                          "complete runs whose inputs are unchanged, run the others "
                          "(the same folder as a run from scratch, byte for byte, but "
                          "for timings.csv, the one file of measured times)")
    run.add_argument("--real-time", type=_positive("factor"), metavar="FACTOR",
                     help="pace the run so that simulated time advances at FACTOR x "
                          "wall-clock time (1: real time; one run only, not with --dask); "
                          "overruns and the achieved factor go to timings.csv and the "
                          "terminal; results are the same as unpaced")
    run.add_argument("--check-step", action="store_true",
                     help="run each complete run again at step/2 and step/4 (Model "
                          "Exchange tolerances divided alike) and write, per metric and "
                          "recorded signal, the change, the observed order and the "
                          "remaining error into DIR/step_check.json and the page "
                          "(docs/metrics.md)")
    run.set_defaults(func=_cmd_run)

    check = sub.add_parser("validate", help="check a manifest against its FMUs, run nothing",
                           parents=[selection, debug],
                           description="Check a manifest against its FMUs' model "
                                       "descriptions, then instantiate and initialise "
                                       "each FMU once with each run's parameters (in a "
                                       "process of its own) to catch values an FMU "
                                       "refuses. Runs no step.")
    check.add_argument("--no-init", action="store_true",
                       help="skip instantiating and initialising the FMUs")
    check.add_argument("--timeout", type=_timeout, metavar="SECONDS",
                       help="limit of each FMU's instantiation and initialisation (default: "
                            "the manifest's [simulation] timeout, else 60 s)")
    check.set_defaults(func=_cmd_validate)

    report = sub.add_parser(
        "report", help="(re)build a result folder's index.html", parents=[debug],
        description="Write DIR/index.html (and the comparison figures sweep_metrics.png "
                    "or montecarlo_scatter.png) from the files of a result folder of "
                    "'agv-cosim run': runs, metrics, figures, provenance, links to the raw "
                    "files; a static page that opens from disk. Only files the report "
                    "wrote before are replaced (exit 2, nothing written, otherwise).")
    report.add_argument("folder", metavar="DIR", help="a result folder of agv-cosim run")
    report.set_defaults(func=_cmd_report)

    listing = sub.add_parser("list", help="list FMUs and their variables", parents=[debug])
    listing.add_argument("path", nargs="?", default="fmus",
                         help="an FMU or a folder of FMUs (default: fmus)")
    listing.set_defaults(func=_cmd_list)

    export = sub.add_parser(
        "export-ssp", help="write one run of a manifest as an SSP 1.0 package",
        description="Write one run (one variant, no sweep) of a manifest as a "
                    "self-contained SSP 1.0 package: SystemStructure.ssd (components, "
                    "connectors with units, connections, parameter values, default "
                    "experiment with the fixed step libcosim reads) and the FMUs under "
                    "resources/.")
    export.add_argument("manifest", help="experiment manifest (TOML)")
    export.add_argument("--variant", metavar="NAME", help="the variant to export")
    export.add_argument("--set", action="append", default=[], metavar="COMP.PARAM=VALUE",
                        help="override a parameter (repeatable)")
    export.add_argument("-o", "--output", required=True, metavar="FILE.ssp",
                        help="the package to write")
    export.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                        help="show tracebacks on errors")
    export.set_defaults(func=_cmd_export_ssp)

    ident = sub.add_parser(
        "identify", help="identify the steering-actuator models a, b, c from a measured "
                         "input/output record (seed 000's procedure)", parents=[debug],
        description="Seed 000's identification on a measured record (CSV: a time column "
                    "and the actuator's command [V] and wheel angle [rad]): the eq 4 "
                    "Butterworth pre-filter (zero-phase), initial values removed, dead "
                    "time estimated, then an output-error fit of each model's FMU "
                    "parameters (a: K, tau; b: K; c: num1, num0, den1, den0, tau) with "
                    "standard errors. Writes DIR/identified.json, identify.png, "
                    "identified_variants.toml (variants ready to run), identify_run.json "
                    "and index.html. Exit 2, one line, for a record that cannot be "
                    "identified from. docs/identify.md.")
    ident.add_argument("data", metavar="DATA.csv", help="the measured record (CSV with a "
                                                        "header row)")
    ident.add_argument("--input", required=True, metavar="COL",
                       help="the command column (motor voltage u [V])")
    ident.add_argument("--output", required=True, metavar="COL",
                       help="the response column (wheel angle alpha [rad])")
    ident.add_argument("--out", required=True, metavar="DIR", help="output folder")
    ident.add_argument("--time", default="time", metavar="COL",
                       help="the time column [s], uniformly sampled (default: time)")
    ident.add_argument("--models", default="a,b,c", metavar="a,b,c",
                       help="the models to fit (default: a,b,c)")
    ident.add_argument("--cutoff", type=_positive("number of Hz", " of Hz"), default=30.0,
                       metavar="HZ",
                       help="pre-filter cut-off [Hz] (default: 30, seed 000 eq 4)")
    ident.add_argument("--order", type=int, default=3, metavar="N",
                       help="pre-filter order (default: 3, seed 000 eq 4)")
    ident.add_argument("--overwrite", action="store_true",
                       help="replace DIR even if it is not a result folder of agv-cosim")
    ident.set_defaults(func=_cmd_identify)

    tuner = sub.add_parser(
        "tune", help="tune parameters (a controller's gains) to minimise a metric over "
                     "every run of a manifest", parents=[debug],
        description="Minimise the [tune] objective of a manifest (a metric of its "
                    "[metrics], or a weighted sum) over the bounded [tune.parameters], "
                    "its mean or worst case over every run (variants and sweep points). "
                    "Each batch of candidates runs through the workers as a sweep "
                    "does; a candidate whose run fails is infeasible and the search goes "
                    "on. Writes DIR/tune.json (best parameters and objective, every "
                    "trial, the seed: the same manifest gives the same bytes), "
                    "tuned_variant.toml, index.html comparing the original and the "
                    "tuned parameters on every run, and their runs under original/ and "
                    "tuned/. Exit 2, one line, for a bad [tune]. docs/tune.md.")
    tuner.add_argument("manifest", help="experiment manifest (TOML) with a [tune] table")
    tuner.add_argument("--out", required=True, metavar="DIR", help="output folder")
    _worker_options(tuner, timeout="a run still going then is stopped and its candidate "
                                   "is infeasible")
    tuner.add_argument("--quiet", action="store_true",
                       help="no progress lines on stderr")
    tuner.set_defaults(func=_cmd_tune)

    fitting = sub.add_parser(
        "fit", help="fit parameters of a manifest's run to measured data ([fit] table)",
        parents=[debug],
        description="Fit the [fit] table's parameters (bounds; start: the manifest's "
                    "value) so that the run's signals match the measured columns of "
                    "[fit] data, the co-simulation itself the model (output error, "
                    "bounded least squares). The runs of each iteration go through the "
                    "worker pool (--jobs) or a Dask cluster (--dask). Writes DIR/fit.json, "
                    "fit_variant.toml (a variant with the fitted values), fitted/ (the run "
                    "at the fitted values), fit.png, fit_run.json and index.html. Exit 2 "
                    "on bad input and when the fit does not converge (the folder is kept, "
                    "marked), 1 when a run fails. docs/fit.md.")
    fitting.add_argument("manifest", metavar="MANIFEST", help="the manifest (TOML) with a "
                                                              "[fit] table")
    fitting.add_argument("--out", required=True, metavar="DIR", help="output folder")
    fitting.add_argument("--variant", metavar="NAME",
                         help="the variant whose run is fitted (a manifest with several)")
    _worker_options(fitting)
    fitting.add_argument("--max-evaluations", type=int, metavar="N",
                         help="the solver's budget of evaluations (default: 100 per "
                              "parameter); a fit that needs more is not converged")
    fitting.set_defaults(func=_cmd_fit)
    parser.commands = dict(sub.choices)
    return parser


def _dispatch(args: argparse.Namespace) -> int:
    command: Callable[[argparse.Namespace], int] = args.func
    if getattr(args, "manifest", None) is None:
        return command(args)
    from .ssp.importer import opened

    # a .ssp package given as the manifest is read into the same Manifest a file gives
    with opened(args.manifest) as manifest:
        if manifest is not None:
            args.manifest = manifest
        return command(args)


def _report(args: argparse.Namespace, text: str, code: int) -> int:
    """One line on stderr (the traceback first with ``--debug``); return ``code``."""
    if args.debug:
        traceback.print_exc()
    _say(f"agv-cosim: {text}")
    return code


def _interrupted(args: argparse.Namespace, name: str, error: BaseException) -> int:
    kept = kept_summary(error)
    return _report(args, f"interrupted by {name}" + (f"; {kept}" if kept else
                                                    " (no result folder was completed)"),
                   exit_code(error))


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``agv-cosim`` console script; returns the exit code."""
    from .errors import (
        FolderLost,
        Interrupted,
        ManifestError,
        OutputError,
        ReportError,
        UnreadableFile,
    )
    from .lifetime import (
        clean_stale_scratch,
        termination_signals,
        use_own_scratch_for_multiprocessing,
    )

    args = make_parser().parse_args(argv)
    if not hasattr(args, "debug"):
        args.debug = False
    try:
        with termination_signals():
            use_own_scratch_for_multiprocessing()
            if args.command != "list":
                clean_stale_scratch()
            return _dispatch(args)
    except BrokenPipeError:
        # the reader went away (e.g. `agv-cosim list | head`): stop quietly
        sys.stdout = None
        return 0
    except (ManifestError, OutputError, UnreadableFile, FolderLost, ReportError,
            OSError) as error:  # OSError: the system refused (disk full, permissions, ...)
        # every problem found in the manifest, one line each (capped)
        lines = error_lines(error)
        code = _report(args, f"error: {lines[0]}", exit_code(error))
        for more in lines[1:]:
            _say(f"agv-cosim: error: {more}")
        return code
    except KeyboardInterrupt as error:
        return _interrupted(args, "SIGINT", error)
    except Interrupted as error:
        return _interrupted(args, error.name, error)
    except Exception as error:  # noqa: BLE001 - never a traceback without --debug
        return _report(args, f"error: internal error: {type(error).__name__}: {error} "
                       "(run with --debug for the traceback)", 1)


def console() -> None:
    """Entry point of the ``agv-cosim`` console script: :func:`main`, then the process
    ends without the interpreter's finalisation, which tears down every module one by
    one (0.3-2 s with matplotlib and pydantic loaded, longer than many runs). First the
    atexit handlers run (multiprocessing's, the removal of our scratch folders) and
    stdout and stderr are flushed; every file the command wrote is closed by then (the
    result folder is committed before :func:`main` returns). ``--help``, ``--version``
    and usage errors exit through ``SystemExit`` as usual.

    OpenBLAS (numpy's and scipy's linear algebra) runs one thread per process unless
    ``OPENBLAS_NUM_THREADS`` says otherwise: the runs go in parallel as processes, the
    components' matrices are far below OpenBLAS's size for threads, and its idle threads
    spin (about 0.1 s of CPU in every process that imports numpy)."""
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    code = main()
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            if stream is not None:
                stream.flush()
        except (OSError, ValueError):  # the reader went away: nothing more to say
            pass
    os._exit(code)


if __name__ == "__main__":
    console()
