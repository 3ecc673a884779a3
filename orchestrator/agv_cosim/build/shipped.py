"""Files agv-cosim ships besides its Python packages: the experiment manifests and the
FMU loader's C source.

In a checkout (and an editable install of it) they are where the repository keeps them,
``experiments/`` and ``components/fmu_loader/``. A wheel carries copies as package data
in ``agv_cosim/shipped/<kind>/`` (setup.py puts them there). :func:`shipped_dir` finds
either.
"""

from pathlib import Path

__all__ = ["SHIPPED", "shipped_dir"]

#: kind -> (folder in the repository, file patterns shipped). setup.py holds the same
#: table (it runs before this package can be imported); tests/packaging/test_wheel.py checks that
#: an installed wheel has every file.
SHIPPED = {
    "experiments": ("experiments", ("*.toml",)),
    "fmu_loader": ("components/fmu_loader", ("*.c", "*.h")),
}

#: agv_cosim/ (this module is agv_cosim/build/shipped.py).
_PACKAGE = Path(__file__).resolve().parent.parent


def shipped_dir(kind: str) -> Path:
    """The folder holding the shipped files of ``kind`` (a key of :data:`SHIPPED`)."""
    if kind not in SHIPPED:
        raise KeyError(f"no shipped files of kind {kind!r}")
    installed = _PACKAGE / "shipped" / kind
    if installed.is_dir():
        return installed
    return _PACKAGE.parent.parent / SHIPPED[kind][0]
