"""Every error type of agv_cosim, in one place.

The pipeline's stages raise these; the CLI turns each into one line (exit 2 for a user's
mistake, 1 for a failed run). The text of every error names its culprit: the manifest and
key, the FMU, the file, or the component, call and time.
"""

import signal

__all__ = [
    "BuildError", "BundleError", "ClusterError", "ExamplesError", "FolderLost",
    "Interrupted", "ManifestError", "ModelError", "OutputError", "SamplingError",
    "SchemaError", "SimulationError", "SspError", "StandaloneError", "TableError",
    "WorkerUnfit",
]


class ManifestError(Exception):
    """A problem in a manifest, named by the manifest, the key and the culprit."""

    def __init__(self, manifest: object, key: str, problem: str) -> None:
        super().__init__(f"{manifest}: {key}: {problem}")
        self.manifest, self.key, self.problem = str(manifest), key, problem


class SchemaError(ValueError):
    """A value that does not fit the schema: ``key`` (dotted) and ``problem``."""

    def __init__(self, key: str, problem: str) -> None:
        super().__init__(f"{key}: {problem}")
        self.key, self.problem = key, problem


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


class Interrupted(BaseException):
    """A termination signal arrived (a BaseException, like KeyboardInterrupt)."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name
