"""How a command ends: termination signals, child processes, scratch folders.

- :func:`termination_signals` turns SIGTERM and SIGHUP into :class:`Interrupted` (as
  Python turns SIGINT into ``KeyboardInterrupt``), so that the ``finally`` clauses that
  stop the run's child processes and delete its temporary folders run for them too. The
  CLI then prints one line and exits with 128 + the signal number.
- :func:`die_with_parent` (called in every child process) asks the kernel to kill the
  child when its parent dies, also when the parent was killed with SIGKILL and could
  not clean up.
- :func:`scratch_dir` makes every temporary folder of ours as
  ``<tmp>/agv-cosim-<pid>-<kind>-XXXXXXXX``; :func:`clean_stale_scratch` removes those
  whose process is gone (a run killed with SIGKILL leaves them), so the next run cleans
  what an earlier one could not.
- :func:`use_own_scratch_for_multiprocessing` puts multiprocessing's sockets in such a
  scratch folder and stops its fork server and resource tracker at exit
  (:func:`stop_helpers`), so no process of ours outlives the command.
"""

import contextlib
import os
import re
import shutil
import signal
import tempfile
from pathlib import Path

#: Signals that end a run cleanly (SIGINT is Python's KeyboardInterrupt already).
TERMINATION_SIGNALS = (signal.SIGTERM, signal.SIGHUP)
_SCRATCH = re.compile(r"^agv-cosim-(\d+)-")


class Interrupted(BaseException):
    """A termination signal arrived (a BaseException, like KeyboardInterrupt)."""

    def __init__(self, signum):
        super().__init__(signal.Signals(signum).name)
        self.signum = int(signum)

    @property
    def name(self):
        return signal.Signals(self.signum).name


def _raise(signum, frame):
    raise Interrupted(signum)


@contextlib.contextmanager
def termination_signals():
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
def signals_blocked():
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


def die_with_parent():
    """Make the kernel kill this process (SIGKILL) when its parent process ends.

    Linux ``prctl(PR_SET_PDEATHSIG)``; elsewhere nothing (the parent's ``finally``
    still stops its children; only a SIGKILLed parent then leaves them running until
    their next write to the parent fails).
    """
    import ctypes
    import ctypes.util

    parent = os.getppid()
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        pr_set_pdeathsig = 1
        libc.prctl(pr_set_pdeathsig, int(signal.SIGKILL), 0, 0, 0)
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)


def scratch_dir(kind):
    """A new private temporary folder ``agv-cosim-<pid>-<kind>-XXXXXXXX``."""
    return tempfile.mkdtemp(prefix=f"agv-cosim-{os.getpid()}-{kind}-")


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def clean_stale_scratch(tmp=None):
    """Remove our scratch folders whose process no longer exists; return how many.

    Only folders named by :func:`scratch_dir` and owned by this user are touched.
    """
    tmp = Path(tmp or tempfile.gettempdir())
    removed = 0
    try:
        entries = list(tmp.iterdir())
    except OSError:
        return 0
    uid = os.getuid()
    for entry in entries:
        match = _SCRATCH.match(entry.name)
        if not match or int(match.group(1)) == os.getpid():
            continue
        try:
            info = entry.lstat()
        except OSError:
            continue
        if info.st_uid != uid or not entry.is_dir() or entry.is_symlink():
            continue
        if not _alive(int(match.group(1))):
            shutil.rmtree(entry, ignore_errors=True)
            removed += 1
    return removed


def use_own_scratch_for_multiprocessing():
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

    config = multiprocessing.current_process()._config
    if config.get("agv_cosim_scratch") or config.get("tempdir") is not None:
        return
    folder = scratch_dir("mp")
    config["agv_cosim_scratch"] = folder
    if len(folder) <= 80:  # the fork server's socket path must stay under 108 bytes
        config["tempdir"] = folder
    else:
        shutil.rmtree(folder, ignore_errors=True)

    def at_exit():
        stop_helpers()
        shutil.rmtree(folder, ignore_errors=True)

    atexit.register(at_exit)


def stop_helpers():
    """Stop multiprocessing's fork server and resource tracker if they run."""
    try:
        from multiprocessing import forkserver, resource_tracker

        forkserver._forkserver._stop()
        resource_tracker._resource_tracker._stop()
    except Exception:  # noqa: BLE001 - private API; without it they end at our exit
        pass
