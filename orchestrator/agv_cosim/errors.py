"""Every error type of agv_cosim, in one place.

The pipeline's stages raise these; the CLI turns each into one line (exit 2 for a user's
mistake, 1 for a failed run). The text of every error names its culprit: the manifest and
key, the FMU, the file, or the component, call and time.
"""

import difflib
import signal
from collections.abc import Iterable

__all__ = [
    "MAX_REPORTED", "AgvCosimError", "BuildError", "BundleError", "ClusterError", "ExamplesError",
    "FolderLost", "IdentifyError", "Interrupted", "ManifestError", "ModelError",
    "OutputError", "ReportError", "SamplingError", "SchemaError", "SimulationError",
    "SspError", "StandaloneError", "TableError", "UnreadableFile", "WorkerUnfit", "closest",
    "did_you_mean", "kept_summary",
    "FitDataError", "FitError", "FitNotConverged", "TuneError",
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


class ReportError(Exception):
    """The report could not be written whole: its page (none is left) or a figure (the
    page marks it); the text names the file and the reason. The results stay."""


class UnreadableFile(Exception):
    """A file the tool reads that it refuses to read: not a regular file (a FIFO, a
    device, a folder), larger than the limit of its kind, or not text/JSON/CSV as its
    kind must be. The text names the file and the reason (``<path>: <problem>``)."""

    def __init__(self, path: object, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path, self.problem = str(path), problem


class FolderLost(Exception):
    """The folder a run was writing was removed or replaced during the run."""


class ClusterError(Exception):
    """The cluster cannot be used (unreachable scheduler, no workers, ...)."""


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


def kept_summary(error: BaseException) -> str | None:
    """What a stopped run kept, as the command says it: 'k of n run(s) complete kept in
    DIR (marked partial: ...)', from the error's ``kept`` folder and ``results``; None
    when it kept nothing."""
    kept, results = getattr(error, "kept", None), getattr(error, "results", None)
    if kept is None or results is None:
        return None
    complete = sum(r["status"] == "complete" for r in results)
    return (f"{complete} of {len(results)} run(s) complete kept in {kept} (marked partial: "
            "partial.txt, summary.csv)")
