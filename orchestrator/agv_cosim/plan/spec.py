"""A planned run (:class:`RunSpec`) and its label, the name of its result folder."""

import hashlib
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from ..manifest import Component, Connection

__all__ = ["MAX_LABEL", "MAX_RUNS", "RunSpec", "run_label"]


@dataclass
class RunSpec:
    """One run: the resolved components and connections of a variant at one sweep
    point."""

    label: str
    variant: str | None
    point: dict[str, Any]
    components: dict[str, Component]
    overrides: dict[str, Any]
    #: the run's wiring: the base's connections, or the variant's (see
    #: :attr:`agv_cosim.manifest.Manifest.variants`)
    connections: list[Connection]
    events: dict[str, dict[str, Any]] = field(default_factory=dict)


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


