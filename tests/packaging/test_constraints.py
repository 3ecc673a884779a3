"""constraints.txt, the versions `make venv` installs, agrees with pyproject.toml and the venv.

Every distribution that pyproject.toml requires (dependencies and the ``test`` extra) is
pinned there, each pin satisfies the requirement's specifier, and the venv the tests run
in holds exactly the pinned versions (a venv made another way, or upgraded by hand,
computes other last bits: the failure names what differs).
"""

import importlib.metadata
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

REPO = Path(__file__).resolve().parents[2]


def pinned():
    """canonical name -> version of every ``name==version`` line of constraints.txt."""
    pins = {}
    for line in (REPO / "constraints.txt").read_text().splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            name, _, version = line.partition("==")
            assert version, f"constraints.txt: {line!r} is not name==version"
            pins[canonicalize_name(name)] = version
    return pins


def required():
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]
    return [Requirement(text) for text in
            project["dependencies"] + project["optional-dependencies"]["test"]]


def test_every_requirement_is_pinned_within_its_specifier():
    pins = pinned()
    for requirement in required():
        name = canonicalize_name(requirement.name)
        assert name in pins, f"{requirement.name} is not pinned in constraints.txt"
        assert requirement.specifier.contains(pins[name], prereleases=True), \
            f"constraints.txt pins {name}=={pins[name]}, pyproject.toml wants {requirement}"


def test_the_venv_holds_the_pinned_versions():
    installed = {canonicalize_name(d.metadata["Name"]): d.version
                 for d in importlib.metadata.distributions()}
    wrong = [f"{name} {installed.get(name, 'missing')} (pinned {version})"
             for name, version in sorted(pinned().items()) if installed.get(name) != version]
    assert not wrong, ("the venv differs from constraints.txt (make venv installs it): "
                       + ", ".join(wrong))
