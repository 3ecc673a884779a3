"""The ``agv-cosim`` command line."""

import argparse
import sys

from . import __version__


def _cmd_build(args):
    from .build import BuildError, build_fmus

    try:
        results = build_fmus(args.out, force=args.force)
    except BuildError as error:
        print(f"agv-cosim build: error: {error}", file=sys.stderr)
        return 1
    for result in results:
        state = "built" if result.rebuilt else "up to date"
        print(f"{result.fmu}  {state}")
    return 0


def make_parser():
    """The argument parser of ``agv-cosim`` with all its subcommands."""
    parser = argparse.ArgumentParser(prog="agv-cosim", description=__doc__)
    parser.add_argument("--version", action="version", version=f"agv-cosim {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks on errors")
    sub = parser.add_subparsers(dest="command", required=True)

    build = sub.add_parser("build", help="build the component FMUs (only what changed)")
    build.add_argument("--out", default="fmus", help="output folder (default: fmus)")
    build.add_argument("--force", action="store_true", help="rebuild every FMU")
    build.set_defaults(func=_cmd_build)
    return parser


def main(argv=None):
    """Entry point of the ``agv-cosim`` console script."""
    args = make_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
