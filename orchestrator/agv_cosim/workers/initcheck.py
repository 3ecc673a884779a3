"""The initialisation check: each FMU instantiated and initialised once with each run's
parameters (:func:`plan_checks`), in a worker process of the pool
(:func:`run_checks` in :func:`agv_cosim.workers.pool.run_isolated`), never in the
command's. ``agv-cosim run`` hands the checks to its first worker, which then runs: the
FMUs are unpacked, loaded and their cores imported once for both; ``agv-cosim validate``
(:func:`agv_cosim.workers.pool.check_initialisation`) to a worker that runs nothing.
"""

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..errors import ManifestError
from ..execution.instance import FmuInstance, extract_ahead
from ..execution.units import enter_initialisation
from ..manifest import Manifest
from ..system import Job, ModelInfo

__all__ = ["INIT_TIMEOUT", "InitChecks", "plan_checks", "run_checks"]

#: Default limit [s] of the initialisation check, per FMU instance (its instantiation
#: and initialisation), when neither ``--timeout`` nor the manifest's ``[simulation]
#: timeout`` gives one. Far above what a sound FMU needs (a component FMU of this
#: project takes about a second on a loaded 2-core machine).
INIT_TIMEOUT = 60.0


@dataclass
class InitChecks:
    """What the initialisation check of ``jobs`` instantiates (see :func:`plan_checks`).

    ``items``: (component, model, parameter values, start, stop) per distinct (FMU,
    parameter values) pair, for the first component and run that has it; ``where``:
    (component, run label) of each item; ``limit``: seconds each item may take."""

    manifest: Manifest
    items: list[tuple[str, ModelInfo, dict[str, Any], float, float]]
    where: list[tuple[str, str]]
    limit: float

    def error(self, index: int, text: str, refused: bool) -> ManifestError:
        """The check's one-line error for item ``index``: the FMU's refusal
        (``refused``) or what happened to the process that checked it."""
        cname, label = self.where[index]
        return self.manifest.error(f"components.{cname}",
                                   f"the FMU refuses to initialise (run {label}): {text}"
                                   if refused else f"run {label}: {text}")

    def died(self, index: int | None, exitcode: int | None) -> ManifestError:
        """The error when the checking process ended during item ``index``."""
        how = (f"signal {-exitcode}" if exitcode is not None and exitcode < 0
               else f"exit code {exitcode}")
        return self.error(index or 0, f"the FMU's process died ({how}) while it was "
                                      "instantiated and initialised", False)

    def broken(self, index: int | None) -> ManifestError:
        """The error when the checking process wrote something that is no frame."""
        return self.error(index or 0, "the FMU's process wrote data that is no message of "
                                      "agv-cosim into its channel (an FMU writing into a "
                                      "file descriptor it does not own)", False)

    def timed_out(self, index: int | None) -> ManifestError:
        """The error when item ``index`` took longer than :attr:`limit`."""
        return self.error(index or 0, f"the FMU did not finish instantiating and "
                                      f"initialising within {self.limit!r} s and was "
                                      "stopped (--timeout sets the limit)", False)


def plan_checks(manifest: Manifest, jobs: list[Job],
                limit: float | None = None) -> InitChecks | None:
    """The checks of ``jobs``: each distinct (FMU, parameter values) pair once, for the
    first component that has it (time tables are checked when they are read); None
    when there is nothing to check. ``limit`` [s] per FMU (default: the manifest's
    ``[simulation] timeout``, else :data:`INIT_TIMEOUT`)."""
    items, where, seen = [], [], set()
    for job in jobs:
        for cname, info in job.plan.models.items():
            if info.table is not None:
                continue
            values = job.plan.parameters.get(cname, {})
            # an FMU run through each of its interfaces is checked through each
            key = (info.sha256, info.integration is not None, repr(sorted(values.items())))
            if key in seen:
                continue
            seen.add(key)
            items.append((cname, info, values, job.plan.start, job.plan.stop))
            where.append((cname, job.label))
    if not items:
        return None
    return InitChecks(manifest, items, where,
                      limit if limit is not None else (manifest.timeout or INIT_TIMEOUT))


def run_checks(items: list[tuple[str, ModelInfo, dict[str, Any], float, float]],
               send: Callable[[tuple[str, Any]], None]) -> bool:
    """Instantiate, initialise and free each of ``items`` in this process (a pool worker,
    whose extractions are kept: an FMU checked with several parameter sets is unpacked
    once). Sends ``("checking", index)`` before each and ``("failed",
    (index, text))`` at the first refusal; returns whether all passed (the caller then
    sends ``("checked", None)``). After a refusal
    the process must not run FMUs any more (a failed pythonfmu instance may have damaged
    the heap)."""
    extract_ahead(item[1] for item in items)
    for index, (cname, info, values, start, stop) in enumerate(items):
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
                _instantiate_call(info))
            failure = f"{call} failed" + (f": {detail}" if detail else f" ({error})")
        finally:
            if instance is not None:
                instance.close()
        if failure:
            send(("failed", (index, failure)))
            return False
    return True


def _instantiate_call(info: ModelInfo) -> str:
    """The FMI call that instantiates ``info`` as the run does (Model Exchange for an
    integrated component)."""
    if info.fmi_version != "3.0":
        return "fmi2Instantiate"
    return ("fmi3InstantiateModelExchange" if info.integration is not None
            else "fmi3InstantiateCoSimulation")
