"""Facts the documentation states about the build, checked against the build itself:
how many FMUs it writes, and that every output folder the docs build into is ignored
by git."""

import re
import shutil
import subprocess
from pathlib import Path

import pytest

from agv_cosim.build import default_components_dir, slave_scripts

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")),
        ROOT / "components" / "README.md", ROOT / "fmus" / "README.md"]
#: "all 23 FMUs", "23 FMI 3.0 twins", "all 23 components", "23 component FMUs"
COUNT = re.compile(r"\b(?:all )?(?<![.\d])(\d+) "
                   r"(?:component FMUs|FMI [23]\.0 twins|FMUs|components)\b")
#: a count of something else than the build's FMUs (a benchmark's subset, an example)
NOT_THE_BUILD = re.compile(r"\b(?:of|the) (?:\d+ )?(?:test|Reference)\b")


def _counts():
    for doc in DOCS:
        if not doc.is_file():
            continue
        text = doc.read_text()
        for match in COUNT.finditer(text):
            before = text[max(0, match.start() - 40):match.start()]
            if match.group(0).startswith("all ") or "FMUs" in match.group(0) \
                    or "twins" in match.group(0):
                yield doc.relative_to(ROOT).as_posix(), int(match.group(1)), before


def test_every_count_of_the_fmus_in_the_docs_is_the_builds():
    built = len(slave_scripts(default_components_dir()))
    wrong = [(doc, n) for doc, n, before in _counts()
             if n != built and n > 5 and not NOT_THE_BUILD.search(before)]
    assert not wrong, f"the build writes {built} FMUs: {wrong}"
    assert any(n == built for _, n, _ in _counts())  # the docs say it somewhere


def _build_outputs():
    for doc in DOCS:
        if doc.is_file():
            for match in re.finditer(r"agv-cosim build[^\n`]*--out ([^\s`]+)", doc.read_text()):
                folder = match.group(1)
                if not folder.isupper() and not folder.startswith(("/", "$")):
                    yield folder


def test_every_folder_the_docs_build_into_is_ignored_by_git():
    git = shutil.which("git")
    if git is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    folders = sorted(set(_build_outputs()))
    assert "fmus3" in folders
    tracked = [f for f in folders
               if subprocess.run([git, "check-ignore", "-q", f"{f}/AgvVehicle.fmu"],
                                 cwd=ROOT).returncode != 0]
    assert not tracked, f"not in .gitignore: {tracked}"
