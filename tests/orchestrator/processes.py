"""Helpers of the tests that watch processes (imported by the test files beside it).

The tests wait on conditions (a process gone, a file with enough rows, a line printed),
never for a time: ``GUARD`` only bounds a wait whose condition never comes, so that a
broken case fails instead of hanging; on a loaded machine a wait simply lasts longer.
"""

import os
import threading
import time
from pathlib import Path

#: last-resort bound of a wait on a condition [s]: far beyond what the slowest machine
#: needs (a wait ends as soon as its condition holds), reached only when a case is broken
GUARD = 300.0


def wait_until(condition, what, guard=GUARD):
    """Poll ``condition()`` until it is true; AssertionError naming ``what`` after
    ``guard`` seconds. Returns the condition's value."""
    end = time.monotonic() + guard
    while True:
        value = condition()
        if value:
            return value
        if time.monotonic() >= end:
            raise AssertionError(f"{what}: not within {guard:g} s")
        time.sleep(0.05)


def _gone(pid):
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return True
    return state == "Z"


def ended(pid, guard=GUARD):
    """True once process ``pid`` has ended (gone, or a zombie awaiting its reaper);
    False if it still runs after ``guard`` seconds."""
    try:
        wait_until(lambda: _gone(pid), f"process {pid} ended", guard)
    except AssertionError:
        return False
    return True


class Collected:
    """Everything a process writes to a pipe, read by a thread as it comes (so that a
    test can wait for a line while the process runs, and the pipe never fills)."""

    def __init__(self, stream):
        self._fd = stream.fileno()
        self._parts = []
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self):
        while chunk := os.read(self._fd, 65536):
            self._parts.append(chunk)

    @property
    def text(self):
        """What was read so far (decoded, invalid bytes replaced)."""
        return b"".join(self._parts).decode(errors="replace")

    def rest(self, guard=GUARD):
        """Everything, once the pipe has closed (the writer and its children ended)."""
        self._thread.join(guard)
        assert not self._thread.is_alive(), f"the pipe stayed open for {guard:g} s"
        return self.text
