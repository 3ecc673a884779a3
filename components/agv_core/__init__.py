"""agv_core: plain-Python models and control laws of the agv-cosim component set.

Every model here is importable and testable without FMI. The FMU slaves in
``components/slaves`` only map FMI variables onto these classes.

Inside this package every import is relative: the FMUs load a bundled copy of it under a
content-tagged module name (see ``components/slaves/agv_boot.py``), so an absolute
``import agv_core`` would silently mix two versions.
"""

__version__ = "0.1.0"
