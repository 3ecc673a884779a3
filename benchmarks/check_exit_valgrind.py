"""Exit-time memory check: valgrind on hosts that load, run, free an FMU and exit normally.

Two builds of the same FMUs are compared:

loader
    the FMUs as ``agv-cosim build`` makes them (components/fmu_loader: the loader and the
    bridge that implements the FMI API over the slave);
pythonfmu only
    the same FMUs with pythonfmu's own library put back as the binary (how pythonfmu 0.7
    ships them): the "before".

and two of the FMI 3.0 twins (``agv-cosim build --fmi 3``):

FMI 3.0 twin
    as built (the same loader and bridge);
FMI 3.0 twin, pythonfmu3 only
    the same twins with pythonfmu3's own library as the binary: the "before".

Hosts: (1) a Python host (fmpy: ``simulate_fmu`` of the vehicle and of the preview
controller, which imports scipy, then a normal interpreter exit); (2) the plain C host of
tests/interop/c_host (the preview controller), loader build only, since the pythonfmu-only
build cannot load there. A baseline Python process that only imports fmpy, numpy and scipy is
run too: CPython's own reports (glibc's dynamic loader reading ahead in ``strncmp`` while
it expands rpaths of numpy's and scipy's extension modules) are in every Python run and
are not the FMUs' (they also appear when an FMU imports numpy). Every other error is
counted and its first frames are printed; those in exit-time finalisation (``_dl_fini``,
``__run_exit_handlers``, ``__cxa_finalize``) are the defect this checks.

Then ``--runs`` Python host processes per build (default 30) are started without valgrind,
and the ones that do not exit with status 0 are counted. Usage::

    python benchmarks/check_exit_valgrind.py [--runs 30]

Needs valgrind and gcc. Takes about 3-5 minutes.
"""

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import fmpy

ROOT = Path(__file__).resolve().parent.parent
FMUS = ("agv_vehicle", "agv_preview_lq")

PYTHON_HOST = """
import sys, fmpy
for path in sys.argv[1:]:
    fmpy.simulate_fmu(path, stop_time=0.2, step_size=0.01)
print("ok")
"""

ERROR = re.compile(r"Invalid (read|write|free)|uninitialised|Mismatched free")
#: glibc's dynamic loader reading ahead in strncmp while it expands an rpath ($ORIGIN):
#: a known valgrind false positive, in every run that loads numpy's extension modules.
LOADER_READ_AHEAD = re.compile(r"strncmp.*\n(.*\n)*?.*(is_dst|_dl_dst_count|_dl_dst_substitute)")
AT_EXIT = re.compile(r"_dl_fini|__run_exit_handlers|__cxa_finalize")


def library_only(fmu, out, fmi_version):
    """A copy of ``fmu`` whose Linux binary is pythonfmu's (FMI 2.0) or pythonfmu3's
    (FMI 3.0) own library again, as those packages ship FMUs (the bridge left out)."""
    if fmi_version == 3:
        import pythonfmu3 as package
        platform_dir = "x86_64-linux"
    else:
        import pythonfmu as package
        platform_dir = "linux64"
    library = (Path(package.__file__).parent / "resources" / "binaries" / platform_dir /
               "libpythonfmu-export.so").read_bytes()
    target = Path(out) / Path(fmu).name
    with zipfile.ZipFile(fmu) as source, zipfile.ZipFile(target, "w",
                                                         zipfile.ZIP_DEFLATED) as copy:
        for name in source.namelist():
            if name.endswith(".bridge.so"):
                continue
            data = source.read(name)
            if name.startswith(f"binaries/{platform_dir}/") and name.endswith(".so"):
                data = library
            copy.writestr(name, data)
    return target


def valgrind(command, env=None):
    """Run under valgrind; (total errors, error blocks other than the loader read-ahead)."""
    done = subprocess.run(["valgrind", "--num-callers=30", *command], capture_output=True,
                          text=True, env=env, timeout=900)
    total = re.search(r"ERROR SUMMARY: (\d+) errors", done.stderr)
    blocks = re.split(r"\n==\d+== \n", done.stderr)
    ours = [b for b in blocks if ERROR.search(b) and not LOADER_READ_AHEAD.search(b)]
    return (int(total.group(1)) if total else -1), ours, done.returncode


def first_lines(block, n=4):
    return "\n".join(line for line in block.splitlines()[:n])


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--runs", type=int, default=30, help="Python host processes per build")
    args = parser.parse_args(argv)
    for tool in ("valgrind", "gcc"):
        if shutil.which(tool) is None:
            sys.exit(f"check_exit_valgrind: needs {tool} on PATH")

    from agv_cosim.build import build_one, slave_script

    with tempfile.TemporaryDirectory(prefix="agv_exit_") as tmp:
        tmp = Path(tmp)
        loader = [build_one(slave_script(name), tmp / "loader").fmu for name in FMUS]
        (tmp / "plain").mkdir()
        plain = [library_only(fmu, tmp / "plain", 2) for fmu in loader]
        twins = [build_one(slave_script(name), tmp / "fmi3", fmi_version=3).fmu
                 for name in FMUS]
        (tmp / "fmi3_plain").mkdir()
        twins_plain = [library_only(fmu, tmp / "fmi3_plain", 3) for fmu in twins]
        builds = (("pythonfmu only", plain), ("loader", loader),
                  ("FMI 3.0 twin, pythonfmu3 only", twins_plain), ("FMI 3.0 twin", twins))
        script = tmp / "host.py"
        script.write_text(PYTHON_HOST)

        total, ours, _ = valgrind([sys.executable, "-c", "import fmpy, numpy, scipy.linalg"])
        print(f"baseline Python (imports only): {total} valgrind errors, {len(ours)} other "
              "than the loader read-ahead")
        for label, fmus in builds:
            total, ours, code = valgrind([sys.executable, str(script), *map(str, fmus)])
            print(f"Python host, {label}: exit status {code}, {total} valgrind errors, "
                  f"{len(ours)} other than the loader read-ahead, "
                  f"{sum(bool(AT_EXIT.search(b)) for b in ours)} at exit")
            for block in ours[:2]:
                print("   ", first_lines(block).replace("\n", "\n    "))

        host = tmp / "fmi2_host"
        subprocess.run(["gcc", "-O1", f"-I{Path(fmpy.__file__).parent / 'c-code'}", "-o",
                        str(host), str(ROOT / "tests" / "interop" / "c_host" / "fmi2_host.c"),
                        "-ldl"],
                       check=True)
        folder = fmpy.extract(str(loader[1]), unzipdir=str(tmp / "lq"))
        md = fmpy.read_model_description(str(loader[1]))
        outputs = ",".join(str(v.valueReference) for v in md.modelVariables
                           if v.causality == "output")
        # a C program's environment with this Python's venv active (how the FMU finds it)
        env = {"PATH": "/usr/bin:/bin", "VIRTUAL_ENV": sys.prefix,
               **{k: v for k, v in os.environ.items() if k.startswith("OPENBLAS_")}}
        total, ours, code = valgrind([str(host), folder, md.coSimulation.modelIdentifier,
                                      md.guid, "0.2", "0.01", outputs], env=env)
        print(f"C host, loader: exit status {code}, {total} valgrind errors, "
              f"{len(ours)} other than the loader read-ahead, "
              f"{sum(bool(AT_EXIT.search(b)) for b in ours)} at exit")
        for block in ours[:2]:
            print("   ", first_lines(block).replace("\n", "\n    "))

        for label, fmus in builds:
            failed = []
            for _ in range(args.runs):
                done = subprocess.run([sys.executable, str(script), *map(str, fmus)],
                                      capture_output=True, text=True, timeout=300)
                if done.returncode != 0:
                    failed.append(done.returncode)
            print(f"{args.runs} Python host processes, {label}: {len(failed)} did not exit "
                  f"with 0 {failed if failed else ''}")


if __name__ == "__main__":
    main()
