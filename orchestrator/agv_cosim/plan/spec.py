"""A planned run (:class:`RunSpec`) and its label, the name of its result folder."""

import hashlib
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from enum import Enum
from typing import Any

from ..manifest import Component, Connection, EventSpec, Variant

__all__ = ["MAX_LABEL", "MAX_RUNS", "Origin", "Override", "RunSpec", "run_label"]


@dataclass(frozen=True)
class Override:
    """One ``--set`` given as a typed value (the API's mapping, :func:`agv_cosim.run`):
    ``name`` (``"component.parameter"`` or an event field) = ``value`` (a bool, int,
    float or str, or a list of them), used as it is: no text to parse."""

    name: str
    value: Any


class Origin(Enum):
    """Where a run's parameter value came from (the last to set it wins, in this order:
    the manifest's ``[components]``, the variant's, ``--set``, the sweep point, the
    Monte Carlo draw)."""

    MANIFEST = "manifest"
    VARIANT = "variant"
    SET = "--set"
    SWEEP = "sweep"
    MONTECARLO = "montecarlo"


@dataclass
class RunSpec:
    """One run, self-contained: the resolved components and connections of a variant at
    one sweep point, its events, and where each parameter value came from."""

    label: str
    variant: str | None
    point: dict[str, Any]
    components: dict[str, Component]
    overrides: dict[str, Any]
    #: the run's wiring: the base's connections, or the variant's
    #: (:attr:`agv_cosim.manifest.Variant.connections`)
    connections: list[Connection]
    events: dict[str, EventSpec] = field(default_factory=dict)
    #: the checked ``[variants.<name>]`` table of :attr:`variant` (None: the base)
    spec: Variant | None = None
    #: ``"component.parameter"`` -> where the value in :attr:`components` came from
    origins: dict[str, Origin] = field(default_factory=dict)

    def parameter_key(self, cname: str, pname: str) -> str:
        """The manifest key that gave the value of ``cname.pname`` (named in a problem
        of that value)."""
        full = f"{cname}.{pname}"
        origin = self.origins.get(full, Origin.MANIFEST)
        if origin is Origin.MONTECARLO:
            return f"montecarlo.parameters.{full}"
        if origin is Origin.SWEEP:
            return f"sweep.{full}"
        if origin is Origin.SET:
            return "--set"
        if origin is Origin.VARIANT:
            return f"variants.{self.variant}.components.{cname}.parameters.{pname}"
        return f"components.{cname}.parameters.{pname}"

    def component_key(self, cname: str, what: str = "fmu") -> str:
        """The key of a component's ``fmu`` (or ``table``): the variant's when it gives
        one."""
        sub = self.spec.components.get(cname) if self.spec is not None else None
        if sub is not None and getattr(sub, what) is not None:
            return f"variants.{self.variant}.components.{cname}.{what}"
        return f"components.{cname}.{what}"


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._=+-]", "_", text)


#: Longest run label (a folder name); longer labels (many or long sweep values) are cut
#: and end in a hash of the full label, so they stay distinct.
MAX_LABEL = 100
#: Most runs of one manifest (variants x sweep points x Monte Carlo samples): each run
#: is a folder of its own and a row of summary.csv; more is refused before any is made.
MAX_RUNS = 100_000


def run_label(parts: Iterable[str]) -> str:
    """The folder name of a run: its slugged parts joined by ``__``, bounded."""
    label = "__".join(_slug(p) for p in parts)
    if len(label) > MAX_LABEL:
        digest = hashlib.sha256(label.encode()).hexdigest()[:12]
        label = f"{label[:MAX_LABEL - 13]}-{digest}"
    return label


