"""Helpers of the tests that watch processes (imported by the test files beside it)."""

import time
from pathlib import Path


def ended(pid, seconds=10.0):
    """True once process ``pid`` has ended within ``seconds`` (gone, or a zombie
    awaiting its reaper); False if it still runs then."""
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            return True
        if state == "Z":
            return True
        time.sleep(0.05)
    return False
