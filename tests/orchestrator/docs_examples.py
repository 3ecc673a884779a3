"""A docs page's worked example run as the page gives it and its output compared with
what the page shows (imported by the docs tests of several folders: tests/orchestrator is
on ``sys.path`` through its conftest.py)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:e[-+]?\d+)?")


def block(text: str, language: str) -> str:
    """The first ```` ```language ```` code block of the Markdown ``text``."""
    found = re.search(rf"^```{language}\n(.*?)^```$", text, flags=re.M | re.S)
    assert found, f"no ```{language} block"
    return found.group(1)


def shape(line: str, trailing_blanks: bool = True) -> tuple[str, list[float]]:
    """``line`` with each number written ``#`` (its trailing blanks left out unless
    ``trailing_blanks``), and the numbers."""
    text = line if trailing_blanks else line.rstrip()
    return NUMBER.sub("#", text), [float(n) for n in NUMBER.findall(line)]


def example_env() -> dict[str, str]:
    """The environment an example runs in: this one, BLAS on one thread."""
    return dict(os.environ, OPENBLAS_NUM_THREADS="1")


def assert_prints_what_the_page_shows(page: Path, cwd: Path, timeout: float,
                                      trailing_blanks: bool = True) -> None:
    """Run the first ```` ```python ```` block of the page ``page`` in a Python process
    in ``cwd`` (:func:`example_env`, at most ``timeout`` s): it exits 0 and prints as
    many lines as the page's first ```` ```text ```` block, each the same text as the
    page's (:func:`shape`) with the same numbers to 1e-3 relative."""
    text = page.read_text()
    code, shown = block(text, "python"), block(text, "text")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=cwd, timeout=timeout, env=example_env())
    assert done.returncode == 0, done.stderr
    printed, expected = done.stdout.splitlines(), shown.splitlines()
    assert len(printed) == len(expected), done.stdout
    for got, want in zip(printed, expected):
        (got_text, got_numbers) = shape(got, trailing_blanks)
        (want_text, want_numbers) = shape(want, trailing_blanks)
        assert got_text == want_text, (got, want)
        assert got_numbers == pytest.approx(want_numbers, rel=1e-3, abs=1e-12), (got, want)
