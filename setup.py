"""setuptools hook (the rest of the configuration is in pyproject.toml).

A wheel ships, besides the packages, the experiment manifests and the FMU loader's C
source, which live outside the packages in the repository: ``build_py`` copies them into
``agv_cosim/shipped/<kind>/`` (agv_cosim/build/shipped.py finds them there; an editable install
finds them in the checkout instead).
"""

from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

#: The same table as agv_cosim.build.shipped.SHIPPED: kind -> (repository folder, patterns).
SHIPPED = {
    "experiments": ("experiments", ("*.toml",)),
    "fmu_loader": ("components/fmu_loader", ("*.c", "*.h")),
}


class BuildPyWithShippedFiles(build_py):
    """build_py that also copies the shipped files into the build's agv_cosim package."""

    def run(self):
        super().run()
        if getattr(self, "editable_mode", False):
            return
        root = Path(__file__).resolve().parent
        for kind, (folder, patterns) in SHIPPED.items():
            target = Path(self.build_lib) / "agv_cosim" / "shipped" / kind
            sources = sorted(p for pattern in patterns for p in (root / folder).glob(pattern))
            if not sources:
                raise SystemExit(f"setup.py: nothing to ship from {folder}/ ({patterns})")
            target.mkdir(parents=True, exist_ok=True)
            for source in sources:
                self.copy_file(str(source), str(target / source.name))


setup(cmdclass={"build_py": BuildPyWithShippedFiles})
