"""Stage 1, the manifest: an experiment's TOML file read and checked into a
:class:`Manifest` (no FMU is opened).

:mod:`.schema` declares the shape of every table (pydantic), :mod:`.load` reads the file
and checks the numbers and names, :mod:`.montecarlo` the ``[montecarlo]`` table. Every
problem is a :class:`~agv_cosim.errors.ManifestError`, ``<manifest>: <key>: <problem>``.
"""

from ..errors import ManifestError
from .load import (
                   MAX_STEPS,
                   Component,
                   Connection,
                   EventSpec,
                   Manifest,
                   Variant,
                   dotted_name,
                   event_key,
                   event_parts,
                   load_manifest,
                   manifest_from_data,
                   parse_toml,
                   read_regular_file,
                   split_name,
                   whole_multiple,
)
from .montecarlo import MonteCarlo

__all__ = ["MAX_STEPS", "Component", "Connection", "EventSpec", "Manifest", "ManifestError",
           "MonteCarlo", "Variant", "dotted_name", "event_key", "event_parts",
           "load_manifest", "manifest_from_data", "parse_toml", "read_regular_file",
           "split_name", "whole_multiple"]
