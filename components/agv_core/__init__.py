"""agv_core: the agv-cosim components, one subpackage per component, and what they share.

Layout (components/README.md has the index):

- ``<component>/`` (vehicle, steering, sensors, ...): the component's FMI-free core
  (plain Python, importable and testable without FMI), its slave scripts ``agv_*.py``,
  its README.md (equations, parameters, signs) and its reference result
  ``<Model>_ref.csv``.
- ``numerics/``: numerics the cores share (angles, the exact arc, finite checks,
  sample-and-hold, path geometry).
- ``fmi/``: the FMI side (the slave adapters, the pythonfmu work-arounds, the boot loader).
  Nothing outside ``fmi/`` and the slave scripts imports it or pythonfmu.
- ``errors.py``, ``units.py``: the parameter error and the unit table, shared by all.

Inside this package every import is relative: the FMUs load a bundled copy of it under a
content-tagged module name (see ``fmi/agv_boot.py``), so an absolute ``import agv_core``
would silently mix two versions.
"""

__version__ = "0.1.0"
