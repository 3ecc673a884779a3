"""How a worker process talks to the parent: frames on a pipe of its own, its stdout and
stderr on another, and the set-up every process that runs FMUs starts with."""

import contextlib
import gc
import os
import pickle
import signal
import struct
import sys
import threading
from collections.abc import Iterator
from multiprocessing import get_context, spawn
from multiprocessing.connection import Connection
from multiprocessing.context import ForkContext, ForkServerContext
from multiprocessing.process import BaseProcess
from pathlib import Path
from typing import IO, Any

from ..files import create_file
from ..lifetime import (
    TERMINATION_SIGNALS,
    close_inherited,
    die_with_parent,
    drop_helper_channels,
    open_fds,
    own_process_group,
)

__all__ = ["FORKSERVER_PRELOAD", "MAX_FRAME", "MAX_OUTPUT", "OUTPUT_FILE", "Frames",
           "OutputLog", "child_setup", "flush_c_stdio", "inherited_fds", "process_context",
           "send_frame", "start_process", "start_without_main"]

# --------------------------------------------------------------------------- channels
#
# A worker reports to the parent through a pipe of its own, in frames the parent reads
# without ever blocking: a 4-byte length, then a pickle of (kind, payload). A worker
# whose FMU writes into that pipe (it inherited the descriptor) is told apart: a frame
# that is too long, does not unpickle or is not a message of ours ends the worker, and
# its run is reported with a reason. The run process's stdout and stderr (fds 1 and 2)
# go to another pipe the parent reads into the run's folder (:class:`OutputLog`).

_FRAME = struct.Struct("!I")
#: Longest frame accepted from a worker [bytes] (a result dict is a few kB).
MAX_FRAME = 16 << 20
_KINDS = ("progress", "message", "done", "checking", "failed", "checked")
#: Output of a run's process (FMU prints, Python warnings) kept in its folder [bytes];
#: what comes after is counted, not kept.
MAX_OUTPUT = 1 << 20
#: The file in a run's folder that holds its process's stdout and stderr (only when the
#: process wrote anything).
OUTPUT_FILE = "output.txt"


def send_frame(fd: int, message: tuple[str, Any]) -> None:
    """Write one frame (see above) to ``fd``, whole."""
    data = pickle.dumps(message, protocol=pickle.HIGHEST_PROTOCOL)
    view = memoryview(_FRAME.pack(len(data)) + data)
    while view:
        view = view[os.write(fd, view):]


class _PipeReader:
    """The parent's end of a pipe from a worker, read without ever blocking."""

    def __init__(self, connection: Connection) -> None:
        self.connection = connection  # keeps the descriptor open
        self.fd = connection.fileno()
        os.set_blocking(self.fd, False)
        self.closed = False

    def chunks(self, limit: int = 1 << 22) -> Iterator[bytes]:
        """What the pipe holds now, in pieces (at most ``limit`` bytes in all); sets
        ``closed`` at its end."""
        got = 0
        while not self.closed and got < limit:
            try:
                chunk = os.read(self.fd, 1 << 16)
            except BlockingIOError:
                return
            except OSError:
                chunk = b""
            if not chunk:
                self.closed = True
                return
            got += len(chunk)
            yield chunk

    def close(self) -> None:
        self.connection.close()


class Frames(_PipeReader):
    """A worker's frame pipe: complete messages, or ``broken`` set when it holds bytes
    that are not ours."""

    def __init__(self, connection: Connection) -> None:
        super().__init__(connection)
        self.buffer = bytearray()
        self.broken: str | None = None  # why the pipe's content cannot be ours

    def read(self) -> list[tuple[str, Any]]:
        """The complete messages now in the pipe."""
        for chunk in self.chunks():
            self.buffer += chunk
        messages = []
        while self.broken is None and len(self.buffer) >= _FRAME.size:
            (size,) = _FRAME.unpack_from(self.buffer)
            if size > MAX_FRAME:
                self.broken = f"a frame of {size} bytes"
                break
            if len(self.buffer) < _FRAME.size + size:
                break
            data = bytes(self.buffer[_FRAME.size:_FRAME.size + size])
            del self.buffer[:_FRAME.size + size]
            try:
                message = pickle.loads(data)  # noqa: S301 - our own worker's process
            except Exception:  # noqa: BLE001 - anything: the pipe holds foreign bytes
                message = None
            if not (isinstance(message, tuple) and len(message) == 2
                    and message[0] in _KINDS):
                self.broken = "bytes that are no message of agv-cosim"
                break
            messages.append(message)
        return messages


class OutputLog(_PipeReader):
    """A run process's stdout and stderr, read from a pipe into ``output.txt`` of the
    run's folder: at most :data:`MAX_OUTPUT` bytes kept, the rest counted. The file is
    created (``O_EXCL | O_NOFOLLOW``) only when there is output."""

    def __init__(self, connection: Connection) -> None:
        super().__init__(connection)
        self.path: Path | None = None
        self.stream: IO[bytes] | None = None
        self.kept = 0
        self.dropped = 0

    def attach(self, run_dir: str | Path) -> Path | None:
        """Output from now on belongs to the run whose folder is ``run_dir``; returns
        the file the earlier run's output was closed into (:meth:`detach`)."""
        closed = self.detach()
        self.path = Path(run_dir) / OUTPUT_FILE
        return closed

    def read(self) -> None:
        for chunk in self.chunks():
            self._keep(chunk)

    def _keep(self, chunk: bytes) -> None:
        room = MAX_OUTPUT - self.kept
        if self.path is None or room <= 0:
            self.dropped += len(chunk)
            return
        if self.stream is None:
            try:
                self.path.parent.mkdir(exist_ok=True)
                self.stream = create_file(self.path, binary=True)
            except OSError:
                self.path = None
                self.dropped += len(chunk)
                return
        part = chunk[:room]
        try:
            self.stream.write(part)
        except OSError:
            pass
        self.kept += len(part)
        self.dropped += len(chunk) - len(part)

    def detach(self) -> Path | None:
        """Close the current run's file (noting what was not kept); returns its path,
        None when the run had no output (no file)."""
        closed = self.path if self.stream is not None else None
        if self.stream is not None:
            try:
                if self.dropped:
                    self.stream.write(f"\n[agv-cosim: {self.dropped} more bytes of output "
                                      f"were not kept (at most {MAX_OUTPUT} bytes a run)]\n"
                                      .encode())
                self.stream.close()
            except OSError:
                pass
        self.stream, self.path, self.kept, self.dropped = None, None, 0, 0
        return closed

    def close(self) -> None:
        self.detach()
        super().close()


def flush_c_stdio() -> None:
    """Flush C stdio buffers of this process (an FMU's printf to a pipe is buffered)."""
    import ctypes

    sys.stdout.flush()
    sys.stderr.flush()
    try:
        ctypes.CDLL(None).fflush(None)  # this process's symbols, libc's among them
    except (OSError, AttributeError):
        pass


def child_setup(output: Connection | None, life: Connection,
                inherited: list[int] | None = None, keep: tuple[Connection, ...] = ()
                ) -> None:
    """Common start of a process that runs FMUs: it drops multiprocessing's helper
    channels and, when forked from the command's process, the descriptors it inherited
    (``inherited``, see :func:`~agv_cosim.lifetime.close_inherited`) but ``output``,
    ``life`` and ``keep`` (an FMU cannot write into them), dies with its parent, leads
    a process group of its own with a guard that ends the group when this process ends
    or when ``life`` (the reading end of a pipe only the command's process writes)
    closes, ignores SIGINT (the parent stops it), takes the default action of SIGTERM
    and SIGHUP, and writes its stdout and stderr to ``output`` (a pipe Connection, or
    None for /dev/null)."""
    drop_helper_channels()
    if inherited is not None:
        close_inherited(inherited, {c.fileno() for c in (output, life, *keep)
                                    if c is not None})
    die_with_parent()
    own_process_group(life.fileno())
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for sig in TERMINATION_SIGNALS:  # a forked child has the command's handlers
        signal.signal(sig, signal.SIG_DFL)
    target = os.open(os.devnull, os.O_WRONLY) if output is None else output.fileno()
    for fd in (1, 2):
        os.dup2(target, fd)
    if output is None:
        os.close(target)
    else:
        output.close()
    if inherited is not None:  # forked: sys.stdout and sys.stderr are the command's objects
        sys.stdout = open(1, "w", errors="backslashreplace", closefd=False)  # noqa: SIM115
        sys.stderr = open(2, "w", errors="backslashreplace", buffering=1,  # noqa: SIM115
                          closefd=False)


_starting = threading.Lock()


@contextlib.contextmanager
def _main_left_alone() -> Iterator[None]:
    """Context in which the processes this thread starts do not import ``__main__``.

    multiprocessing's start data (``spawn.get_preparation_data``) tells a forkserver or
    spawn child to import the parent's main module (``init_main_from_path`` for a
    script, ``init_main_from_name`` for ``python -m``) before it runs its target. A
    script without an ``if __name__ == "__main__":`` guard would then run again in every
    child, and fail there. Our children's targets live in agv_cosim and need nothing
    from ``__main__``, so those two entries are left out of what this thread sends;
    other threads' processes get multiprocessing's data unchanged."""
    with _starting:
        original = spawn.get_preparation_data
        caller = threading.get_ident()

        def preparation_data(name: str) -> dict[str, Any]:
            data: dict[str, Any] = original(name)
            if threading.get_ident() == caller:
                data.pop("init_main_from_path", None)
                data.pop("init_main_from_name", None)
            return data

        spawn.get_preparation_data = preparation_data
        try:
            yield
        finally:
            spawn.get_preparation_data = original


def start_without_main(process: BaseProcess) -> None:
    """``process.start()``, the child not importing the caller's ``__main__`` (a script
    or notebook calling agv_cosim needs no ``if __name__ == "__main__":`` guard)."""
    with _main_left_alone():
        process.start()


#: Modules the fork server (used when this process has other threads, see
#: :func:`process_context`) imports once, so that each worker starts with them: the pool
#: (:mod:`.pool`, and with it numpy) and fmpy's wrapper. Not the scientific modules a
#: component core may import (scipy.signal, ...): a worker imports those when an FMU of
#: its run needs them, once per worker. A module missing here is skipped by the fork
#: server.
FORKSERVER_PRELOAD = ("agv_cosim.workers.pool", "fmpy.fmi2", "numpy")


def process_context() -> ForkContext | ForkServerContext:
    """The multiprocessing context of the processes that run FMUs.

    ``fork`` while this process runs a single thread: the child starts at once, with
    every module this process has imported, and no fork server is started (it closes
    what it inherited, see :func:`child_setup`). Otherwise
    the ``forkserver`` (preloaded with :data:`FORKSERVER_PRELOAD`): forking a process
    in which another thread runs may copy a lock that thread holds.
    """
    if threading.active_count() == 1:
        return get_context("fork")
    context = get_context("forkserver")
    context.set_forkserver_preload(list(FORKSERVER_PRELOAD))
    return context


def inherited_fds(context: ForkContext | ForkServerContext) -> list[int] | None:
    """What a child of ``context`` is to close of what it inherits: this process's open
    descriptors when it forks from this process, else None (a fork server's child
    inherits only what it is given); flushes this process's stdout and stderr first (a
    forked child would write their buffers again)."""
    if context.get_start_method() != "fork":
        return None
    sys.stdout.flush()
    sys.stderr.flush()
    return open_fds()


def start_process(process: Any, context: ForkContext | ForkServerContext) -> None:
    """Start ``process`` (of ``context``); when it is forked from this process, with this
    process's objects frozen out of the garbage collector meanwhile (``gc.freeze``):
    the child's collections then never walk the command's heap (the jobs, the
    manifest), which would cost time and copy its pages; else (the fork server) without
    the caller's ``__main__`` (:func:`start_without_main`)."""
    if context.get_start_method() != "fork":
        start_without_main(process)
        return
    gc.freeze()
    try:
        process.start()
    finally:
        gc.unfreeze()
