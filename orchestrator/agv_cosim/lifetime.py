"""How a command ends: termination signals, child processes, scratch folders.

- :func:`termination_signals` turns SIGTERM and SIGHUP into :class:`Interrupted` (as
  Python turns SIGINT into ``KeyboardInterrupt``), so that the ``finally`` clauses that
  stop the run's child processes and delete its temporary folders run for them too. The
  CLI then prints one line and exits with 128 + the signal number.
- :func:`die_with_parent` (called in every child process) asks the kernel to kill the
  child when its parent dies, also when the parent was killed with SIGKILL and could
  not clean up.
- :func:`scratch_dir` makes every temporary folder of ours as
  ``<tmp>/agv-cosim-<pid>-<kind>-XXXXXXXX`` (mode 0700) and puts our marker file
  (:data:`SCRATCH_MARKER`, created with ``O_EXCL | O_NOFOLLOW``: the process id and its
  start time) in it; :func:`clean_stale_scratch` removes the folders that carry that
  marker and whose process is gone (a run killed with SIGKILL leaves them), so the next
  run cleans what an earlier one could not. A folder without our marker is never
  removed, whatever its name.
- :func:`own_process_group` (called in every child process that runs FMUs) makes the
  child the leader of a process group of its own, with a guard process in it that kills
  the whole group when the child ends: processes an FMU forks end with its run.
- A process that leaves the group (``setsid()``, ``setpgid()``) is still ended: the
  child that runs FMUs is a child subreaper (``PR_SET_CHILD_SUBREAPER``), so every process
  started under it stays in its tree of descendants while it lives, whatever group or
  session it moves to, and :func:`kill_group` stops the child, kills that whole tree,
  then the group. The command's process is a subreaper too while its runs go on
  (:class:`Orphans`): a process left behind by a child that ended is handed to it, and
  :func:`end_orphans` kills it. Linux (the tree is read from ``/proc``);
  elsewhere only the group.
- :func:`use_own_scratch_for_multiprocessing` puts multiprocessing's sockets in such a
  scratch folder and stops its fork server and resource tracker at exit
  (:func:`stop_helpers`), so no process of ours outlives the command.
"""

import contextlib
import json
import os
import re
import shutil
import signal
import stat
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from types import FrameType
from typing import Any, NoReturn

from .errors import Interrupted

#: Signals that end a run cleanly (SIGINT is Python's KeyboardInterrupt already).
TERMINATION_SIGNALS = (signal.SIGTERM, signal.SIGHUP)
_SCRATCH = re.compile(r"^agv-cosim-(\d+)-")
#: The marker file in every scratch folder of ours (JSON: tool, pid, process start time).
SCRATCH_MARKER = ".agv-cosim-scratch"
#: Flags of every file we create: a new file (never an existing one), never through a
#: symbolic link, not inherited by programs we start.
CREATE_FLAGS = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC


def _raise(signum: int, frame: FrameType | None) -> NoReturn:
    raise Interrupted(signum)


@contextlib.contextmanager
def termination_signals() -> Iterator[None]:
    """Context in which SIGTERM and SIGHUP raise :class:`Interrupted` (main thread)."""
    previous = {}
    try:
        for sig in TERMINATION_SIGNALS:
            previous[sig] = signal.signal(sig, _raise)
    except ValueError:  # not the main thread: leave the handlers alone
        pass
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


@contextlib.contextmanager
def signals_blocked() -> Iterator[None]:
    """Context in which termination signals wait (a rename that must not be cut)."""
    wanted = {signal.SIGINT, *TERMINATION_SIGNALS}
    try:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, wanted)
    except (AttributeError, OSError):
        yield
        return
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def ignore_termination() -> Callable[[], None]:
    """Ignore SIGINT, SIGTERM and SIGHUP from now on (the last writes after an
    interruption are not cut by a second signal); return a function that puts the
    previous handlers back."""
    previous = {}
    for sig in (signal.SIGINT, *TERMINATION_SIGNALS):
        try:
            previous[sig] = signal.signal(sig, signal.SIG_IGN)
        except ValueError:  # not the main thread
            break

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)

    return restore


def _prctl_pdeathsig(signum: int) -> bool:
    """``prctl(PR_SET_PDEATHSIG, signum)``; False where it is not available."""
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)  # this process's symbols, libc's among them
        result: int = libc.prctl(1, int(signum), 0, 0, 0)  # restype c_int: a Python int
        return result == 0
    except (OSError, AttributeError):
        return False


#: prctl options (linux/prctl.h)
_PR_SET_CHILD_SUBREAPER = 36
_PR_GET_CHILD_SUBREAPER = 37


def _prctl(option: int, value: int = 0) -> int | None:
    """``prctl(option, value)``'s result, or None where it is not available."""
    import ctypes

    try:
        libc = ctypes.CDLL(None, use_errno=True)
        return int(libc.prctl(option, value, 0, 0, 0))
    except (OSError, AttributeError):
        return None


def _subreaper() -> int:
    """This process's child-subreaper setting (0 off, also where unknown)."""
    import ctypes

    value = ctypes.c_int(0)
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        if libc.prctl(_PR_GET_CHILD_SUBREAPER, ctypes.byref(value), 0, 0, 0) != 0:
            return 0
    except (OSError, AttributeError):
        return 0
    return value.value


def _process_table() -> dict[int, tuple[int, str]]:
    """Every visible process: pid -> (parent pid, state letter) from ``/proc``."""
    table: dict[int, tuple[int, str]] = {}
    try:
        names = os.listdir("/proc")
    except OSError:
        return table
    for name in names:
        if not name.isdigit():
            continue
        try:
            with open(f"/proc/{name}/stat", "rb") as stream:
                fields = stream.read().rsplit(b")", 1)[1].split()
            table[int(name)] = (int(fields[1]), fields[0].decode("ascii", "replace"))
        except (OSError, IndexError, ValueError):
            continue
    return table


def descendants(pid: int, table: dict[int, tuple[int, str]] | None = None) -> list[int]:
    """The processes below ``pid`` (children, their children, ...) that have not ended
    (zombies left out), from ``/proc``; empty where it cannot be read."""
    table = _process_table() if table is None else table
    children: dict[int, list[int]] = {}
    for child, (parent, _) in table.items():
        children.setdefault(parent, []).append(child)
    found, todo = [], [pid]
    while todo:
        for child in children.get(todo.pop(), ()):
            if child != pid and child not in found:
                found.append(child)
                todo.append(child)
    return [p for p in found if table[p][1] != "Z"]


def _kill_tree(pid: int) -> None:
    """Stop process ``pid`` (still alive, a child subreaper: see
    :func:`own_process_group`) and SIGKILL every process below it but the caller, again
    until none is left (a killed process's children are handed to ``pid``, which stays
    stopped)."""
    try:
        os.kill(pid, signal.SIGSTOP)
    except OSError:
        return
    me = os.getpid()  # the guard, itself below ``pid``, kills the group after this
    for _ in range(200):
        below = [p for p in descendants(pid) if p != me]
        if not below:
            return
        for child in below:
            with contextlib.suppress(OSError):
                os.kill(child, signal.SIGKILL)
        time.sleep(0.005)  # the killed ones exit; their children move to ``pid``


class _Wake(Exception):
    pass


def _wake(signum: int, frame: FrameType | None) -> NoReturn:
    raise _Wake


def own_process_group(life: int | None = None) -> None:
    """Make this process the leader of a process group of its own, with a guard in it.

    Every process an FMU forks (and that does not leave the group) is then in this
    group, so a parent can end the run with ``os.killpg`` (:func:`kill_group`). The
    guard, a forked child that holds no file of ours but ``life``, kills the whole
    group (and every process below this one, also those that left the group; if this
    process went first, those it saw below this one at its last look, every half
    second) as soon as this process ends (``PR_SET_PDEATHSIG``, and a check every half second) or
    ``life`` reads as closed: ``life`` is the reading end of a pipe whose
    writing end only the command's own process holds, so it closes when that process
    ends, however (a SIGKILL included). The FMU's processes thus end with the run
    however it ends, and none keeps one of our pipes open. Linux; elsewhere only the
    group.
    """
    import select

    os.setpgid(0, 0)
    _prctl(_PR_SET_CHILD_SUBREAPER, 1)  # what leaves the group stays below this process
    leader = os.getpid()
    try:
        guard = os.fork()
    except OSError:
        return
    if guard:
        return
    try:  # the guard: nothing of the parent's but the group and ``life``
        keep = [] if life is None else [life]
        os.closerange(0, min(keep) if keep else 65536)
        if life is not None:
            os.closerange(life + 1, 65536)
        signal.signal(signal.SIGTERM, _wake)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGHUP, signal.SIG_IGN)
        _prctl_pdeathsig(signal.SIGTERM)
        me = os.getpid()
        seen: dict[int, int | None] = {}  # below the leader at the last look: start time
        try:
            while os.getppid() == leader:
                if select.select(keep, [], [], 0.5)[0]:
                    break  # the command's process ended: its pipe reads as closed
                below = {p: _start_time(p) for p in descendants(leader) if p != me}
                if os.getppid() == leader:  # the leader lived through the look: valid
                    seen = below
        except (_Wake, OSError):
            pass
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        if os.getppid() == leader:  # the processes that left the group, then the group
            _kill_tree(leader)
        # those seen below the leader that left the group, if the leader went first
        for pid, start in seen.items():
            if start is not None and _start_time(pid) == start:
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGKILL)
        os.killpg(0, signal.SIGKILL)
    finally:
        os._exit(0)


def drop_helper_channels() -> None:
    """Close, in a child of the fork server, the descriptors multiprocessing gives it
    to reach its helpers (the fork server's liveness pipe, the resource tracker's
    pipe): an FMU that writes into every descriptor it finds cannot then break them for
    the runs that follow, and the fork server ends when our process does. The child
    starts no process through multiprocessing, so it needs neither."""
    try:
        from multiprocessing import forkserver, resource_tracker
    except ImportError:  # pragma: no cover
        return
    for holder, name in ((forkserver._forkserver, "_forkserver_alive_fd"),
                         (resource_tracker._resource_tracker, "_fd")):
        fd = getattr(holder, name, None)
        if isinstance(fd, int) and fd > 2:
            try:
                os.close(fd)
            except OSError:
                pass
            setattr(holder, name, None)


def open_fds() -> list[int]:
    """The file descriptors open in this process now (Linux ``/proc/self/fd``; elsewhere
    an empty list)."""
    try:
        return sorted(int(name) for name in os.listdir("/proc/self/fd"))
    except OSError:
        return []


def close_inherited(fds: list[int], keep: set[int]) -> None:
    """Close, in a child forked from the command's process, the descriptors ``fds`` it
    inherited (the parent's :func:`open_fds` before the fork) but those in ``keep`` and
    the standard ones: an FMU that writes into every descriptor it finds cannot reach
    the parent's other pipes (the other workers', the life pipe's writing end)."""
    for fd in fds:
        if fd > 2 and fd not in keep:
            try:
                os.close(fd)
            except OSError:
                pass


def kill_group(process: Any) -> None:
    """SIGKILL the process group led by ``process`` (a multiprocessing Process started
    with :func:`own_process_group`), else the process alone; while ``process`` runs,
    first every process below it (:func:`_kill_tree`: those that left its group too)."""
    pid = process.pid
    if pid is None:
        return
    try:
        alive = process.is_alive()  # not reaped: ``pid`` is still its own
    except (OSError, ValueError, AssertionError):
        alive = False
    if alive:
        _kill_tree(pid)
    try:
        os.killpg(pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        try:
            process.kill()
        except (OSError, ValueError, AttributeError):
            pass


class Orphans:
    """While it is open, this process is a child subreaper: a process left behind by a
    process of ours that ended (its parent gone) is handed to this one, and
    :meth:`sweep` ends those handed over so far (:func:`end_orphans`, sparing the
    children this process had when it opened). :meth:`close` sweeps once more and puts
    the setting back. Linux; elsewhere :meth:`sweep` finds nothing."""

    def __init__(self) -> None:
        self._before = _subreaper()
        self._known = frozenset(_children())  # from before: no orphans of ours
        self._set = not self._before and _prctl(_PR_SET_CHILD_SUBREAPER, 1) == 0

    def sweep(self) -> list[int]:
        """End the orphans handed over so far; their pids."""
        return end_orphans(self._known) if self._set or self._before else []

    def close(self) -> None:
        try:
            self.sweep()
        finally:
            if self._set:
                _prctl(_PR_SET_CHILD_SUBREAPER, 0)
                self._set = False


def _children() -> list[int]:
    """This process's children that have not ended (from ``/proc``)."""
    me = os.getpid()
    return [pid for pid, (parent, state) in _process_table().items()
            if parent == me and state != "Z"]


def end_orphans(known: frozenset[int] = frozenset()) -> list[int]:
    """SIGKILL (and reap) the children of this process that it did not start, with
    everything below them: those handed to it as a child subreaper
    (:class:`Orphans`). Spared: ``known`` and the processes multiprocessing
    started (workers, figure processes, its fork server and resource tracker). Returns
    the pids ended."""
    import multiprocessing

    ours = set(known)
    ours.update(p.pid for p in multiprocessing.active_children() if p.pid is not None)
    try:
        from multiprocessing import forkserver, resource_tracker

        ours.add(getattr(forkserver._forkserver, "_forkserver_pid", None) or 0)
        ours.add(getattr(resource_tracker._resource_tracker, "_pid", None) or 0)
    except ImportError:  # pragma: no cover
        pass
    ended = []
    for pid in _children():
        if pid in ours:
            continue
        for below in [*descendants(pid), pid]:
            with contextlib.suppress(OSError):
                os.kill(below, signal.SIGKILL)
        with contextlib.suppress(ChildProcessError, OSError):
            os.waitpid(pid, 0)
        ended.append(pid)
    return ended


def die_with_parent() -> None:
    """Make the kernel kill this process (SIGKILL) when its parent process ends.

    Linux ``prctl(PR_SET_PDEATHSIG)``; elsewhere nothing (the parent's ``finally``
    still stops its children; only a SIGKILLed parent then leaves them running until
    their next write to the parent fails).
    """
    import ctypes

    parent = os.getppid()
    try:
        libc = ctypes.CDLL(None, use_errno=True)  # this process's symbols, libc's among them
        pr_set_pdeathsig = 1
        libc.prctl(pr_set_pdeathsig, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)


def _start_time(pid: int) -> int | None:
    """Start time of process ``pid`` in clock ticks since boot (Linux), or None."""
    try:
        with open(f"/proc/{int(pid)}/stat", "rb") as stream:
            fields = stream.read().rsplit(b")", 1)[1].split()
        return int(fields[19])
    except (OSError, IndexError, ValueError):
        return None


def scratch_dir(kind: str) -> str:
    """A new private temporary folder ``agv-cosim-<pid>-<kind>-XXXXXXXX`` (0700) that
    carries our marker (:data:`SCRATCH_MARKER`)."""
    folder = tempfile.mkdtemp(prefix=f"agv-cosim-{os.getpid()}-{kind}-")
    try:
        fd = os.open(os.path.join(folder, SCRATCH_MARKER), CREATE_FLAGS, 0o600)
        with os.fdopen(fd, "w", encoding="utf-8") as stream:
            json.dump({"tool": "agv-cosim", "pid": os.getpid(),
                       "start": _start_time(os.getpid())}, stream)
    except BaseException:
        shutil.rmtree(folder, ignore_errors=True)
        raise
    return folder


def _alive(pid: int, start: int | None = None) -> bool:
    """True when process ``pid`` exists (and, if ``start`` is known, started then)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    if start is not None:
        now = _start_time(pid)
        return now is None or now == start  # another process under a reused pid: gone
    return True


def _marker_owner(folder: str | Path, uid: int) -> tuple[int, int | None] | None:
    """(pid, start time) from our marker in ``folder``, or None when it has no valid one
    (missing, a link, not a regular file of this user, not our JSON)."""
    try:
        fd = os.open(os.path.join(folder, SCRATCH_MARKER),
                     os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError:
        return None
    try:
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode) or info.st_uid != uid or info.st_size > 4096:
            return None
        data = json.loads(os.read(fd, 4096).decode("utf-8"))
    except (OSError, ValueError):
        return None
    finally:
        os.close(fd)
    if not isinstance(data, dict) or data.get("tool") != "agv-cosim":
        return None
    pid, start = data.get("pid"), data.get("start")
    if isinstance(pid, bool) or not isinstance(pid, int) or pid <= 0:
        return None
    return pid, (start if isinstance(start, int) and not isinstance(start, bool) else None)


def clean_stale_scratch(tmp: str | Path | None = None) -> int:
    """Remove our scratch folders whose process no longer exists; return how many.

    Only a folder of this user (not a link) named like :func:`scratch_dir`'s *and*
    holding our marker file is removed, and only when the process the marker names is
    gone: a folder of anyone else's, whatever its name, is never touched.
    """
    tmp = Path(tmp or tempfile.gettempdir())
    removed = 0
    try:
        entries = list(tmp.iterdir())
    except OSError:
        return 0
    uid = os.getuid()
    for entry in entries:
        if not _SCRATCH.match(entry.name):
            continue
        try:
            info = entry.lstat()
        except OSError:
            continue
        if info.st_uid != uid or not stat.S_ISDIR(info.st_mode):
            continue
        owner = _marker_owner(entry, uid)
        if owner is None or owner[0] == os.getpid():
            continue
        if not _alive(*owner):
            shutil.rmtree(entry, ignore_errors=True)
            removed += 1
    return removed


def use_own_scratch_for_multiprocessing() -> None:
    """Once per process: multiprocessing's sockets in a scratch folder of ours, and its
    helper processes stopped at exit.

    Its default folder (``pymp-*``) is removed only by an orderly exit; ours is removed
    by the next run when this process was killed. At exit (``atexit``, before the
    interpreter ends) the fork server and resource tracker are stopped and waited for,
    so no process of ours outlives the command. Within one process (the tests call the
    CLI many times) the fork server is kept between commands.
    """
    import atexit
    import multiprocessing

    config = multiprocessing.current_process()._config  # type: ignore[attr-defined]
    if config.get("agv_cosim_scratch") or config.get("tempdir") is not None:
        return
    folder = scratch_dir("mp")
    config["agv_cosim_scratch"] = folder
    if len(folder) <= 80:  # the fork server's socket path must stay under 108 bytes
        config["tempdir"] = folder
    else:
        shutil.rmtree(folder, ignore_errors=True)

    def at_exit() -> None:
        stop_helpers()
        shutil.rmtree(folder, ignore_errors=True)

    atexit.register(at_exit)


def stop_helpers() -> None:
    """Stop multiprocessing's fork server and resource tracker if they run."""
    try:
        from multiprocessing import forkserver, resource_tracker

        forkserver._forkserver._stop()  # type: ignore[attr-defined]
        resource_tracker._resource_tracker._stop()  # type: ignore[attr-defined]
    except Exception:  # noqa: BLE001 - private API; without it they end at our exit
        pass
