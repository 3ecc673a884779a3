"""SSP 1.0 packages: one run of a manifest written as an ``.ssp`` (:mod:`.exporter`), and
a package read into the :class:`~agv_cosim.manifest.Manifest` a manifest file gives
(:mod:`.importer`); :mod:`.common` is their shared vocabulary."""

from .exporter import export_ssp
from .importer import load_ssp, opened

__all__ = ["export_ssp", "load_ssp", "opened"]
