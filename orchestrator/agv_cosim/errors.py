"""Every error type of agv_cosim, in one place.

The pipeline's stages raise these; the CLI turns each into one line (exit 2 for a user's
mistake, 1 for a failed run). The text of every error names its culprit: the manifest and
key, the FMU, the file, or the component, call and time.
"""

import difflib
import signal
from collections.abc import Callable, Iterable
from typing import Any

__all__ = [
    "MAX_REPORTED", "AgvCosimError", "BuildError", "BundleError", "ClusterError",
    "ClusterStopped", "ExamplesError", "FolderLost", "IdentifyError", "Interrupted",
    "InterruptedRuns", "KeyboardInterruptedRuns", "ManifestError", "ModelError",
    "OutputError", "ReportError", "RunsStopped", "SamplingError", "SchemaError",
    "SimulationError", "SspError", "StandaloneError", "TableError", "UnreadableFile",
    "WorkerUnfit", "closest", "did_you_mean", "error_lines", "exit_code", "kept_summary",
    "FitDataError", "FitError", "FitNotConverged", "TrialFailed", "TuneError",
    "ArchiveRefused",
]

#: Most problems of one manifest reported at once (one line each).
MAX_REPORTED = 20


def closest(name: str, known: Iterable[str]) -> str | None:
    """The name of ``known`` closest to ``name`` (difflib's ratio >= 0.6), or None."""
    found = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return found[0] if found else None


def did_you_mean(name: str, known: Iterable[str]) -> str:
    """``" (did you mean 'x'?)"`` for the name of ``known`` closest to ``name``, else ``""``."""
    match = closest(name, known)
    return f" (did you mean '{match}'?)" if match is not None else ""


class ManifestError(Exception):
    """A problem in a manifest, named by the manifest (and the line of the key, when
    known), the key and the culprit: ``<manifest>[:<line>]: <key>: <problem>``.

    ``others`` holds further problems of the same manifest found in the same check.
    """

    exit_code = 2

    def __init__(self, manifest: object, key: str, problem: str,
                 line: int | None = None) -> None:
        where = f"{manifest}:{line}" if line is not None else f"{manifest}"
        super().__init__(f"{where}: {key}: {problem}")
        self.manifest, self.key, self.problem, self.line = str(manifest), key, problem, line
        self.others: list[ManifestError] = []

    def lines(self, limit: int = MAX_REPORTED) -> list[str]:
        """This problem and the others, one line each, at most ``limit`` lines (the last
        says how many more were found)."""
        texts = [str(self)] + [str(other) for other in self.others]
        if len(texts) > limit:
            hidden = len(texts) - limit + 1
            texts = texts[:limit - 1] + [f"{self.manifest}: {hidden} more problem(s) not "
                                         "shown"]
        return texts


class SchemaError(ValueError):
    """A value that does not fit the schema: ``key`` (dotted) and ``problem``;
    ``others`` holds the further problems found in the same data."""

    def __init__(self, key: str, problem: str) -> None:
        super().__init__(f"{key}: {problem}")
        self.key, self.problem = key, problem
        self.others: list[SchemaError] = []


class SspError(ManifestError):
    """An SSP package we cannot read or run; the text is ``<package>: <element>: <problem>``."""


class SamplingError(ValueError):
    """A distribution whose numbers a double cannot hold (the text says which)."""


class ModelError(Exception):
    """An FMU is missing, unreadable or not an FMI 2.0/3.0 co-simulation FMU."""


class TableError(Exception):
    """A time table that cannot be used; the text names the file, row and column."""


class SimulationError(Exception):
    """The run stopped: an FMU failed or produced a non-finite value."""


class OutputError(Exception):
    """An output folder we must not (or cannot) write; the text names the path."""

    exit_code = 2


class ReportError(Exception):
    """The report could not be written whole: its page (none is left) or a figure (the
    page marks it); the text names the file and the reason. The results stay: ``kept``
    is then their folder and ``results`` one result per run (or None)."""

    exit_code = 1

    def __init__(self, message: str, kept: object = None,
                 results: list[Any] | None = None) -> None:
        super().__init__(message)
        self.kept, self.results = kept, results


class UnreadableFile(Exception):
    """A file the tool reads that it refuses to read: not a regular file (a FIFO, a
    device, a folder), larger than the limit of its kind, or not text/JSON/CSV as its
    kind must be. The text names the file and the reason (``<path>: <problem>``)."""

    exit_code = 2

    def __init__(self, path: object, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path, self.problem = str(path), problem


class ArchiveRefused(ValueError):
    """A zip archive (an SSP package, an FMU) refused before or while it is unpacked
    (:mod:`agv_cosim.archive`): ``archive`` names it, ``reason`` says why (one line)."""

    def __init__(self, archive: object, reason: str) -> None:
        super().__init__(f"{archive}: {reason}")
        self.archive, self.reason = str(archive), reason


class FolderLost(Exception):
    """The folder a run was writing was removed or replaced during the run."""

    exit_code = 1


class ClusterError(Exception):
    """The cluster cannot be used (unreachable scheduler, no workers, ...)."""

    exit_code = 1


class WorkerUnfit(RuntimeError):
    """This worker cannot run any run (a setting or its FMU cache): nothing will run."""


class BuildError(RuntimeError):
    """An FMU could not be built, or the built FMU is not valid FMI."""


class BundleError(RuntimeError):
    """The modules or distributions an FMU needs cannot be derived."""


class StandaloneError(RuntimeError):
    """The standalone runtime cannot be assembled on this machine."""


class ExamplesError(Exception):
    """The examples cannot be copied (a user's file in the way, a bad shipped manifest)."""


class AgvCosimError(Exception):
    """What the Python API (:mod:`agv_cosim.api`) raises for every mistake and failure
    the command line reports as an error: ``str()`` is the line ``agv-cosim`` prints
    after ``agv-cosim: error:``; ``lines`` holds every line (a manifest's problems, one
    each); ``exit_code`` is the command's (2 bad input, 1 a failure); ``kept`` is the
    result folder kept marked partial (or None)."""

    def __init__(self, message: str, lines: list[str] | None = None, exit_code: int = 2,
                 kept: object = None) -> None:
        super().__init__(message)
        self.lines = list(lines) if lines else [message]
        self.exit_code = exit_code
        self.kept = kept


class IdentifyError(AgvCosimError):
    """A record ``agv-cosim identify`` cannot identify from (a file that is not CSV, a
    missing column, a value that is not a finite number, time not increasing, data too
    short or without excitation): one line naming the culprit, exit 2."""


class FitDataError(AgvCosimError):
    """Measured data ``fit`` cannot use (a file that is not CSV, no ``time`` column or
    no column a signal names, a value that is not a finite number, time not increasing,
    data outside the simulated interval): one line naming the file, the line and the
    column, exit 2."""


class FitError(AgvCosimError):
    """A fit that cannot be set up or carried on (no parameter or signal, min >= max, a
    start outside its bounds, a weight that is not a positive number, a simulated signal
    missing or not finite): one line naming the culprit, exit 2."""


class FitNotConverged(FitError):
    """The fit stopped before its solver converged; ``result`` holds the best point
    found (a :class:`agv_cosim.fitting.FitResult`, marked not converged)."""

    def __init__(self, message: str, result: object = None) -> None:
        super().__init__(message)
        self.result = result


class TrialFailed(AgvCosimError):
    """A run of a fit or a tuning (:mod:`agv_cosim.pipeline.trials`) did not complete:
    one line naming its parameter values and its reason, exit 1 (the command stops)."""

    def __init__(self, message: str) -> None:
        super().__init__(message, exit_code=1)


class TuneError(AgvCosimError):
    """A tuning that cannot be set up or carried on (no parameter, min >= max, a start
    outside its bounds, an unknown aggregate, a metric missing from a run): one line
    naming the culprit, exit 2."""


class Interrupted(BaseException):
    """A termination signal arrived (a BaseException, like KeyboardInterrupt)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name

    @property
    def exit_code(self) -> int:
        """128 + the signal's number, as a shell reports a process the signal ended."""
        return 128 + self.signum


class RunsStopped(BaseException):
    """Runs stopped before all ended (a termination signal, a cluster gone), with what
    was done: raised by the runners (:class:`~agv_cosim.workers.runner.Runner`) as the
    kind of the stop it carries (:meth:`of`: a :class:`KeyboardInterrupt`, an
    :class:`Interrupted` or a :class:`ClusterError`), so that every ``except`` of that
    kind still takes it.

    ``results``: one result per job (the runs not done ``not run``); ``restore``: puts
    the termination signals back as they were (ignored since the stop, so that the
    caller can keep what was done); ``reason``: why, as partial.txt says it; ``kept``:
    the result folder the command kept marked partial (None until then, or when it
    kept none)."""

    def __init__(self, *args: object, results: list[Any] | None = None,
                 restore: Callable[[], None] | None = None, reason: str = "") -> None:
        BaseException.__init__(self, *args)  # the text of the stop's own kind
        self.results: list[Any] = list(results or [])
        self._restore = restore
        self.reason = reason
        self.kept: object = None

    def restore(self) -> None:
        """The termination signals back as they were before the stop (once)."""
        restore, self._restore = self._restore, None
        if restore is not None:
            restore()

    @staticmethod
    def of(stop: BaseException, results: list[Any],
           restore: Callable[[], None] | None = None, reason: str = "") -> "RunsStopped":
        """A RunsStopped of the kind of ``stop`` (a KeyboardInterrupt, an Interrupted
        or a ClusterError), with its text and signal; ``reason`` defaults to
        'interrupted by SIGNAL'."""
        if isinstance(stop, Interrupted):
            return InterruptedRuns(stop.signum, results=results, restore=restore,
                                   reason=reason or f"interrupted by {stop.name}")
        if isinstance(stop, KeyboardInterrupt):
            return KeyboardInterruptedRuns(*stop.args, results=results, restore=restore,
                                           reason=reason or "interrupted by SIGINT")
        if isinstance(stop, ClusterError):
            return ClusterStopped(str(stop), results=results, restore=restore,
                                  reason=reason or str(stop))
        raise TypeError(f"runs are not stopped by {type(stop).__name__}")


class InterruptedRuns(RunsStopped, Interrupted):
    """Runs stopped by a termination signal (an :class:`Interrupted`)."""

    def __init__(self, signum: int, results: list[Any] | None = None,
                 restore: Callable[[], None] | None = None, reason: str = "") -> None:
        RunsStopped.__init__(self, signal.Signals(signum).name, results=results,
                             restore=restore, reason=reason)
        self.signum = int(signum)


class KeyboardInterruptedRuns(RunsStopped, KeyboardInterrupt):
    """Runs stopped by SIGINT through Python's handler (a :class:`KeyboardInterrupt`)."""


class ClusterStopped(RunsStopped, ClusterError):
    """Runs stopped because the cluster went away (a :class:`ClusterError`)."""


def exit_code(error: BaseException) -> int:
    """The exit code of ``agv-cosim`` for ``error``, for the command line and the API
    alike: the error type's own (``exit_code``: 2 bad input, 1 a failure, 128 + N for
    signal N), 130 for a KeyboardInterrupt, else 1 (the system refused: an OSError; an
    internal error)."""
    if isinstance(error, KeyboardInterrupt):
        return 128 + signal.SIGINT
    code = getattr(error, "exit_code", None)
    return code if isinstance(code, int) else 1


def error_lines(error: BaseException) -> list[str]:
    """The lines ``agv-cosim`` prints for ``error`` after ``agv-cosim: error:``, one per
    problem (a manifest's, capped: :meth:`ManifestError.lines`); for an OSError its file
    and the system's reason; for runs a cluster stopped, what was kept."""
    if isinstance(error, ManifestError):
        return error.lines()
    if isinstance(error, OSError):
        where = f"{error.filename}: " if error.filename else ""
        return [f"{where}{error.strerror or str(error) or type(error).__name__}"]
    kept = kept_summary(error)
    return [f"{error}" + (f"; {kept}" if kept else "")]


def kept_summary(error: BaseException) -> str | None:
    """What a stopped run kept, as the command says it: 'k of n run(s) complete kept in
    DIR (marked partial: ...)', from a :class:`RunsStopped`'s ``kept`` folder and
    ``results``; None when it kept nothing."""
    if not isinstance(error, RunsStopped) or error.kept is None:
        return None
    kept, results = error.kept, error.results
    complete = sum(r["status"] == "complete" for r in results)
    return (f"{complete} of {len(results)} run(s) complete kept in {kept} (marked partial: "
            "partial.txt, summary.csv)")
