"""The ``agv-cosim`` command line.

Exit codes: 0 success; 1 a run that failed or is partial, a metrics error, a failed build
or an error of the system (disk full, ...); 2 bad input (one line
``agv-cosim: error: <manifest>: <key>: <problem>`` on stderr; also an output folder that
is not ours, or one another run is writing); 128 + N when ended by signal N (SIGINT,
SIGTERM, SIGHUP), with no result folder completed. Every error is one line on stderr;
``--debug`` adds the traceback and changes nothing else (not the exit code).
"""

import argparse
import sys
import traceback

from . import __version__
from .ssp_export import add_cli as add_ssp_cli
from .ssp_import import opened


def _error(text):
    print(f"agv-cosim: error: {text}", file=sys.stderr)
    return 2


def _cmd_build(args):
    from .build import BuildError, build_fmus

    try:
        results = build_fmus(args.out, force=args.force, fmi_version=args.fmi,
                             standalone=args.standalone)
    except BuildError as error:
        print(f"agv-cosim build: error: {error}", file=sys.stderr)
        return 1
    for result in results:
        state = "built" if result.rebuilt else "up to date"
        print(f"{result.fmu}  {state}")
    return 0


def _warn(warnings, quiet=False):
    for warning in warnings:
        print(f"agv-cosim: warning: {warning}", file=sys.stderr)


def _cmd_validate(args):
    from .runner import check_initialisation, prepare

    manifest, jobs, warnings = prepare(args.manifest, args.variant, args.set)
    _warn(warnings)
    if not args.no_init:
        check_initialisation(manifest, jobs)
    print(f"{manifest.path}: ok: {len(jobs)} run(s), {len(manifest.components)} "
          f"component(s), {len(manifest.connections)} connection(s), "
          f"{manifest.algorithm}")
    return 0


def _cmd_run(args):
    from .runner import execute, prepare

    if args.jobs is not None and args.jobs < 1:
        return _error("--jobs: must be >= 1")
    manifest, jobs, warnings = prepare(args.manifest, args.variant, args.set)
    _warn(warnings)
    from .distributed import ClusterError  # issue 16: --dask

    try:
        target, results = execute(manifest, jobs, args.out, args.jobs, args.quiet,
                                  overwrite=args.overwrite, dask=args.dask)
    except ClusterError as error:
        print(f"agv-cosim: error: {error}", file=sys.stderr)
        return 1
    bad = [r for r in results if r["status"] != "complete"]
    for result in bad:
        print(f"agv-cosim: run {result['label']} {result['status']}: {result['error']}",
              file=sys.stderr)
    unmeasured = [r for r in results if r.get("metrics_error")]
    for result in unmeasured:
        print(f"agv-cosim: run {result['label']}: metrics: {result['metrics_error']}",
              file=sys.stderr)
    if not args.quiet:
        print(f"{target}: {len(results) - len(bad)}/{len(results)} run(s) complete")
    return 1 if bad or unmeasured else 0


def _cmd_list(args):
    from pathlib import Path

    from .model import ModelError, describe, find_fmus, read_model

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
            print(f"agv-cosim: error: {fmu}: {error}", file=sys.stderr)
            status = 2
            continue
        if i:
            print()
        print(describe(info))
    return status


def make_parser():
    """The argument parser of ``agv-cosim`` with all its subcommands."""
    parser = argparse.ArgumentParser(prog="agv-cosim", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"agv-cosim {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    debug = argparse.ArgumentParser(add_help=False)
    debug.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                       help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True)

    build = sub.add_parser("build", help="build the component FMUs (only what changed)",
                           parents=[debug])
    build.add_argument("--out", default="fmus", help="output folder (default: fmus)")
    build.add_argument("--force", action="store_true", help="rebuild every FMU")
    build.add_argument("--fmi", type=int, choices=(2, 3), default=2,
                       help="FMI version of the FMUs: 2 (default) or 3 (the FMI 3.0 twins, "
                            "built with pythonfmu3)")
    build.add_argument("--standalone", action="store_true",
                       help="FMUs that carry their own Python runtime and packages (run "
                            "on a Linux x86-64 machine without Python; tens of MB each)")
    build.set_defaults(func=_cmd_build)

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
                                     "DIR/summary.csv and plots. Exit 0 if all runs are "
                                     "complete, 1 if any failed or is partial, 2 on bad "
                                     "input.")
    run.add_argument("--out", metavar="DIR",
                     help="output folder (default: results/<manifest name>)")
    run.add_argument("--quiet", action="store_true", help="no progress bars or summary")
    run.add_argument("--overwrite", action="store_true",
                     help="replace DIR even if it is not a result folder of agv-cosim "
                          "(without it such a folder is refused)")
    run.add_argument("--jobs", type=int, metavar="N",
                     help="runs at once, in worker processes (a worker is replaced after a "
                          "run that did not complete; default: one per core)")
    run.add_argument("--dask", metavar="ADDRESS",  # issue 16: agv_cosim.distributed
                     help="run on the Dask cluster whose scheduler is at ADDRESS "
                          "(tcp://HOST:PORT; see docs/dask.md); default: local processes")
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
    check.set_defaults(func=_cmd_validate)

    listing = sub.add_parser("list", help="list FMUs and their variables", parents=[debug])
    listing.add_argument("path", nargs="?", default="fmus",
                         help="an FMU or a folder of FMUs (default: fmus)")
    listing.set_defaults(func=_cmd_list)
    add_ssp_cli(sub)
    return parser


def _dispatch(args):
    # a .ssp package given as the manifest is read into the same Manifest a file gives
    with opened(getattr(args, "manifest", None)) as manifest:
        if manifest is not None:
            args.manifest = manifest
        return args.func(args)


def _report(args, text, code):
    """One line on stderr (the traceback first with ``--debug``); return ``code``."""
    if args.debug:
        traceback.print_exc()
    print(f"agv-cosim: {text}", file=sys.stderr)
    return code


def main(argv=None):
    """Entry point of the ``agv-cosim`` console script; returns the exit code."""
    from .lifetime import (Interrupted, clean_stale_scratch, termination_signals,
                           use_own_scratch_for_multiprocessing)
    from .manifest import ManifestError
    from .results import OutputError

    args = make_parser().parse_args(argv)
    if not hasattr(args, "debug"):
        args.debug = False
    try:
        with termination_signals():
            use_own_scratch_for_multiprocessing()
            if args.command != "list":
                clean_stale_scratch()
            return _dispatch(args)
    except (ManifestError, OutputError) as error:
        return _report(args, f"error: {error}", 2)
    except BrokenPipeError:
        # the reader went away (e.g. `agv-cosim list | head`): stop quietly
        sys.stdout = None
        return 0
    except KeyboardInterrupt:
        return _report(args, "interrupted by SIGINT (no result folder was completed)", 130)
    except Interrupted as signal:
        return _report(args, f"interrupted by {signal.name} (no result folder was "
                       "completed)", 128 + signal.signum)
    except OSError as error:  # the system refused (disk full, permissions, ...)
        where = f"{error.filename}: " if error.filename else ""
        return _report(args, f"error: {where}{error.strerror or error}", 1)
    except Exception as error:  # noqa: BLE001 - never a traceback without --debug
        return _report(args, f"error: internal error: {type(error).__name__}: {error} "
                       "(run with --debug for the traceback)", 1)


if __name__ == "__main__":
    sys.exit(main())
