"""agv_cosim.build.bundle: which part of agv_core an FMU ships and which distributions it declares.

On small made-up packages (the real FMUs' lists are checked in test_fmu_requirements.py).
"""

import importlib.metadata
import textwrap

import pytest

from agv_cosim.build.bundle import bundle_of, installed_requirements, requirements_text
from agv_cosim.errors import BundleError

NONE = ((), ())  # no child process: the requirement list given
BOOT = ["agv_boot"]  # the boot loader: shipped by the FMU, not a distribution


def package(root, files):
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))
    return root


def script(tmp_path, text):
    path = tmp_path / "agv_thing.py"
    path.write_text(textwrap.dedent(text))
    return path


CORE = {
    "__init__.py": '"""root"""\n',
    "errors.py": "class E(Exception): pass\n",
    "units.py": "import json\n",
    "numerics/__init__.py": "",
    "numerics/arc.py": "import math\nfrom ..errors import E\n",
    "numerics/paths.py": "import numpy as np\nfrom .arc import E\n",
    "thing/__init__.py": "",
    "thing/core.py": "from ..numerics import arc\n\ndef lazy():\n    from .. import units\n",
    "other/__init__.py": "",
    "other/big.py": "import scipy\n",
}


def test_the_bundle_is_what_the_script_reaches(tmp_path):
    core = package(tmp_path / "core", CORE)
    slave = script(tmp_path, 'from agv_boot import load_core\ncore = load_core("thing.core")\n')
    bundle = bundle_of(slave, core, local=BOOT, requirements=NONE)
    # thing.core -> numerics.arc (a submodule named in `from ..numerics import arc`) ->
    # errors; units through the import inside a function; every __init__ on the way
    assert bundle.files == ("__init__.py", "errors.py", "numerics/__init__.py",
                            "numerics/arc.py", "thing/__init__.py", "thing/core.py",
                            "units.py")
    assert bundle.imports == ()  # math, json: the standard library; agv_boot: the FMU's


def test_the_tag_follows_the_shipped_files_and_the_requirements(tmp_path):
    core = package(tmp_path / "core", CORE)
    slave = script(tmp_path, 'from agv_boot import load_core\ncore = load_core("thing.core")\n')
    first = bundle_of(slave, core, local=BOOT, requirements=NONE).tag
    (core / "other" / "big.py").write_text("import scipy  # changed\n")
    assert bundle_of(slave, core, local=BOOT, requirements=NONE).tag == first  # not shipped
    assert bundle_of(slave, core, local=BOOT, requirements=((("numpy", "1.0"),), ())).tag != first
    (core / "numerics" / "arc.py").write_text("import math\nfrom ..errors import E  # x\n")
    assert bundle_of(slave, core, local=BOOT, requirements=NONE).tag != first
    overridden = bundle_of(slave, core, local=BOOT, requirements=NONE,
                           overrides=[("thing/core.py", "from .. import errors\n")])
    assert overridden.files == ("__init__.py", "errors.py", "thing/__init__.py", "thing/core.py")


@pytest.mark.parametrize("slave_text, module, message", [
    ('from agv_boot import load_core\nNAME = "thing.core"\ncore = load_core(NAME)\n', None,
     "string literals only"),
    ('from agv_boot import load_core\ncore = load_core("thing.nothing")\n', None,
     "not a module of agv_core"),
    ('from agv_boot import load_core\ncore = load_core("thing.core")\n',
     "import importlib\nmod = importlib.import_module('numpy')\n", "a dynamic import"),
    ('from agv_boot import load_core\ncore = load_core("thing.core")\n',
     "import agv_core.errors\n", "an absolute import of agv_core"),
    ('from agv_boot import load_core\ncore = load_core("thing.core")\n',
     "from ..missing import x\n", "no module 'missing'"),
])
def test_what_the_walk_cannot_follow_is_refused(tmp_path, slave_text, module, message):
    core = package(tmp_path / "core", CORE)
    if module is not None:
        (core / "thing" / "core.py").write_text(module)
    with pytest.raises(BundleError, match=message):
        bundle_of(script(tmp_path, slave_text), core, local=BOOT, requirements=NONE)


def test_distributions_come_from_what_the_imports_load(tmp_path):
    """numpy imported by the package: listed as the package's own, at its installed
    version; the wrapper package the FMU carries (here: pretend numpy is carried) is not."""
    core = package(tmp_path / "core", CORE)
    slave = script(tmp_path, 'from agv_boot import load_core\ncore = load_core("numerics.paths")\n')
    bundle = bundle_of(slave, core, local=BOOT)
    assert bundle.imports == ("numpy",)
    assert bundle.direct == (("numpy", importlib.metadata.version("numpy")),)
    assert bundle_of(slave, core, local=BOOT, shipped=["numpy"]).direct == ()


def test_a_requirement_list_is_reused_only_while_its_versions_are_installed():
    numpy = importlib.metadata.version("numpy")
    text = requirements_text((("numpy", numpy),), (("packaging",
                                                     importlib.metadata.version("packaging")),))
    direct, indirect = installed_requirements(text)
    assert direct == (("numpy", numpy),) and indirect[0][0] == "packaging"
    assert installed_requirements(text.replace(f"numpy=={numpy}", "numpy==0.0.1")) is None
    assert installed_requirements(text + "not-a-distribution-here==1.0\n") is None
    assert installed_requirements("numpy>=1.24\nscipy>=1.10\n") is None  # an older FMU's
