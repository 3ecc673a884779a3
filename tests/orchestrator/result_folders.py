"""Result folders compared file by file (imported by the test files of several folders:
tests/orchestrator is on ``sys.path`` through its conftest.py)."""

from pathlib import Path

from agv_cosim.report.records import TIMINGS


def folder_contents(root):
    """Relative path -> bytes of every file under ``root`` but timings.csv (which must
    be there)."""
    root = Path(root)
    assert (root / TIMINGS).is_file()
    return {str(path.relative_to(root)): path.read_bytes()
            for path in sorted(root.rglob("*")) if path.is_file() and path.name != TIMINGS}


def assert_same_folder(resumed, clean):
    mine, theirs = folder_contents(resumed), folder_contents(clean)
    assert sorted(mine) == sorted(theirs)
    for name in theirs:
        assert mine[name] == theirs[name], name
    return len(theirs)
