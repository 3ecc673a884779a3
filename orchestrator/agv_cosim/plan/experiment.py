"""What the system stage needs of a manifest, as one frozen :class:`Experiment`.

The system check (:func:`agv_cosim.system.validate`) takes an :class:`Experiment` and the
planned runs (:class:`~agv_cosim.plan.spec.RunSpec`, each self-contained): the
simulation settings, the recorded, held and swept names, the base's wiring, where
relative file names start, and how a problem at a manifest key is reported.
"""

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

from ..errors import ManifestError
from ..manifest import Connection, Manifest
from ..manifest.load import line_of, step_index
from .runs import plan_runs
from .spec import RunSpec

__all__ = ["Experiment"]


@dataclass(frozen=True)
class Experiment:
    """A manifest's settings that every run of it shares, read once (:meth:`of`)."""

    #: the manifest file (or SSP package) every message names
    path: Path
    #: ``[simulation]``: start, stop, communication step [s] and the master algorithm
    start: float
    stop: float
    step: float
    algorithm: str
    #: ``[record] variables`` (None: every numeric output of a run's components)
    record: tuple[str, ...] | None
    #: ``held``: inputs left unconnected on purpose, ``"component.input"``
    held: tuple[str, ...]
    #: the ``[sweep]`` names, in the manifest's order
    sweep: tuple[str, ...]
    #: the folder relative file names in parameter and event values start from
    files_dir: Path
    #: the base's connections (a variant's run has its own wiring:
    #: :attr:`RunSpec.connections`)
    connections: tuple[Connection, ...]
    #: the declared variants' names, in the manifest's order
    variants: tuple[str, ...]
    #: the first run of a variant, planned without ``--set`` (what the ``held`` check
    #: reads of a variant that is not being run)
    plan_variant: Callable[[str], RunSpec] = field(repr=False, compare=False)
    #: dotted key -> its line in the manifest file (empty for an SSP package)
    lines: Mapping[str, int] = field(default_factory=dict, repr=False)

    @classmethod
    def of(cls, manifest: Manifest) -> "Experiment":
        """The experiment of a loaded and checked manifest."""
        return cls(path=manifest.path, start=manifest.start, stop=manifest.stop,
                   step=manifest.step, algorithm=manifest.algorithm,
                   record=None if manifest.record is None else tuple(manifest.record),
                   held=tuple(manifest.held), sweep=tuple(manifest.sweep),
                   files_dir=manifest.files_dir,
                   connections=tuple(manifest.connections),
                   variants=tuple(manifest.variants),
                   lines=MappingProxyType(dict(manifest.lines)),
                   plan_variant=lambda variant: plan_runs(manifest, [variant])[0])

    def error(self, key: str, problem: str) -> ManifestError:
        """A :class:`ManifestError` of ``key``, with its line when known."""
        return ManifestError(self.path, key, problem, line_of(self.lines, key))

    def step_index(self, at: float) -> int:
        """k of the communication point ``at`` = start + k step [s]."""
        return step_index(self.start, self.step, at)
