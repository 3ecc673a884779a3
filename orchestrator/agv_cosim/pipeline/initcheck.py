"""The initialisation check of ``agv-cosim validate``: each FMU instantiated and
initialised once with each run's parameters, in a child process of its own."""

import os
import shutil
import tempfile
import time
from multiprocessing.connection import Connection, wait
from typing import Any

from ..execution.instance import FmuInstance, keep_extractions
from ..execution.units import enter_initialisation
from ..lifetime import kill_group, scratch_dir
from ..manifest import Manifest
from ..system import Job, ModelInfo
from .channels import Frames, child_setup, send_frame
from .pool import inherited_fds, process_context, start_process

__all__ = ["INIT_TIMEOUT", "check_initialisation"]


def _check_child(checks: list[tuple[str, ModelInfo, dict[str, Any], float, float]],
                 channel: Connection, life: Connection, scratch: str,
                 inherited: list[int] | None = None) -> None:
    """Body of the initialisation check's child: instantiate and initialise each FMU."""
    # an FMU's prints go nowhere: validate writes no results
    child_setup(None, life, inherited, (channel,))
    tempfile.tempdir = scratch
    keep_extractions(scratch)  # an FMU checked with several parameter sets: unpacked once
    fd = channel.fileno()

    def send(message: tuple[str, Any]) -> None:
        try:
            send_frame(fd, message)
        except OSError:
            os._exit(1)

    for index, (cname, info, values, start, stop) in enumerate(checks):
        send(("checking", index))
        instance, failure = None, None
        calls: list[str] = []  # FMI calls after instantiation; the last is the one under way
        try:
            # instances one after the other: the FMU's one extraction serves them all
            instance = FmuInstance(info, cname, shared=True)
            enter_initialisation(instance.slave, info, values, start, stop, calls.append)
            calls.append("fmi3ExitInitializationMode" if info.fmi_version == "3.0"
                         else "fmi2ExitInitializationMode")
            instance.slave.exitInitializationMode()
        except Exception as error:  # noqa: BLE001 - the FMU's refusal is the result
            detail = instance.last_error() if instance is not None else ""
            call = getattr(error, "function", None) or (
                calls[-1] if calls else
                "fmi3InstantiateCoSimulation" if info.fmi_version == "3.0" else "fmi2Instantiate")
            failure = f"{call} failed" + (f": {detail}" if detail else f" ({error})")
        finally:
            if instance is not None:
                instance.close()
        if failure:
            send(("failed", (index, failure)))
            os._exit(0)  # a failed pythonfmu instance may have damaged the heap
    send(("done", None))
    os._exit(0)


#: Default limit [s] of ``validate``'s initialisation check, per FMU instance (its
#: instantiation and initialisation), when neither ``--timeout`` nor the manifest's
#: ``[simulation] timeout`` gives one. Far above what a sound FMU needs (a component
#: FMU of this project takes about a second on a loaded 2-core machine).
INIT_TIMEOUT = 60.0


def check_initialisation(manifest: Manifest, jobs: list[Job],
                         timeout: float | None = None) -> None:
    """Instantiate and initialise each FMU once with each run's parameters.

    Catches what only the FMU knows (a parameter value it refuses), without running.
    The FMUs run in a child process of their own (see the module docstring); each
    distinct (FMU, parameter values) pair is checked once (for the first component
    that has it), and the first refusal stops. An
    FMU that takes longer than ``timeout`` [s] (default: the manifest's ``[simulation]
    timeout``, else :data:`INIT_TIMEOUT`) to instantiate and initialise is stopped.

    Raises
    ------
    ManifestError
        Naming the component, the run, the FMI call and the FMU's own message.
    """
    limit = timeout if timeout is not None else (manifest.timeout or INIT_TIMEOUT)
    checks, where, seen = [], [], set()
    for job in jobs:
        for cname, info in job.plan.models.items():
            if info.table is not None:  # a time table: checked when it was read
                continue
            values = job.plan.parameters.get(cname, {})
            key = (info.sha256, repr(sorted(values.items())))
            if key in seen:
                continue
            seen.add(key)
            checks.append((cname, info, values, job.plan.start, job.plan.stop))
            where.append((cname, job.label))
    if not checks:
        return
    context = process_context()
    reader, writer = context.Pipe(duplex=False)
    life_reader, life_writer = context.Pipe(duplex=False)
    scratch = scratch_dir("check")
    process = context.Process(target=_check_child, name="agv-cosim check",
                              args=(checks, writer, life_reader, scratch,
                                    inherited_fds(context)))
    frames = Frames(reader)
    current, failure, finished = None, None, False
    deadline = time.monotonic() + limit
    try:
        start_process(process, context)
        writer.close()
        while failure is None and not finished:
            now = time.monotonic()
            handles = [process.sentinel] + ([frames.fd] if not frames.closed else [])
            wait(handles, timeout=min(1.0, max(0.0, deadline - now)))
            for kind, payload in frames.read():
                if kind == "checking":
                    current, deadline = payload, time.monotonic() + limit
                elif kind == "failed":
                    failure = (*payload, True)
                elif kind == "done":
                    finished = True
            if failure is not None or finished:
                break
            if frames.broken:
                failure = (current if current is not None else 0,
                           "the FMU's process wrote data that is no message of agv-cosim "
                           "into its channel (an FMU writing into a file descriptor it does "
                           "not own)", False)
            elif not process.is_alive():
                for kind, payload in frames.read():
                    if kind == "failed":
                        failure = (*payload, True)
                    elif kind == "done":
                        finished = True
                if failure is None and not finished:
                    process.join()
                    code = process.exitcode
                    how = f"signal {-code}" if code and code < 0 else f"exit code {code}"
                    failure = (current if current is not None else 0,
                               f"the FMU's process died ({how}) while it was instantiated "
                               "and initialised", False)
            elif time.monotonic() >= deadline:
                failure = (current if current is not None else 0,
                           f"the FMU did not finish instantiating and initialising within "
                           f"{limit!r} s and was stopped (--timeout sets the limit)",
                           False)
    finally:
        kill_group(process)
        if process.pid is not None:
            process.join()
        frames.close()
        life_reader.close()
        life_writer.close()
        shutil.rmtree(scratch, ignore_errors=True)
    if failure is not None:
        index, text, refused = failure
        cname, label = where[index]
        raise manifest.error(f"components.{cname}",
                            f"the FMU refuses to initialise (run {label}): {text}"
                            if refused else f"run {label}: {text}")
