"""Test FMU that misbehaves towards its host process (each behaviour chosen by a
parameter, all off by default):

- ``stdout_bytes``: writes that many bytes a step to file descriptors 1 and 2 (C level,
  ``os.write``) and prints a line with ``print``;
- ``message``: logs this text as a warning through the FMI logger each step (e.g. with
  terminal escape sequences); from ``fail_time`` on [s] (< 0: never) doStep fails with
  it as the error;
- ``log_count``: logs that many messages a step through the FMI logger (info, the last
  of each step a warning);
- ``garbage_time``: from this time on [s] (< 0: never), writes garbage into every open
  file descriptor above 2 that is a pipe (those it inherited from its host);
- ``fork_seconds``: at initialisation forks a helper process that sleeps this long [s]
  holding every descriptor it inherited (0: none); its pid is the output ``helper``;
  with ``leave`` 1 the helper leaves our session and process group (``setsid()``), with
  2 the FMU forks a child that forks the helper (which calls ``setsid()``) and exits at
  once (a daemon's double fork: the helper's parent is gone).
"""

import os
import stat

from agv_boot import load_core

core = load_core("fmi.fmi_slave")


def _pipes():
    found = []
    for name in os.listdir("/proc/self/fd"):
        fd = int(name)
        if fd <= 2:
            continue
        try:
            if stat.S_ISFIFO(os.fstat(fd).st_mode):
                found.append(fd)
        except OSError:
            pass
    return found


class AgvTestRogue(core.fmi.fmi_slave.AgvSlave):
    """Counts time and misbehaves as its parameters ask."""

    description = "Test FMU that writes to stdout, into inherited pipes, or forks"

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        fs = core.fmi.fmi_slave
        self.parameter("stdout_bytes", 0, None, "Bytes written to fds 1 and 2 a step",
                       kind=fs.Integer)
        self.parameter("message", "", None, "Warning logged every step", kind=fs.String)
        self.parameter("log_count", 0, None, "Messages logged a step", kind=fs.Integer)
        self.parameter("fail_time", -1.0, "s", "From then on, doStep fails with message")
        self.parameter("garbage_time", -1.0, "s", "From then on, garbage into pipes")
        self.parameter("fork_seconds", 0.0, "s", "Life of a forked helper (0: none)")
        self.parameter("leave", 0, None, "The helper: 0 stays, 1 setsid, 2 double fork",
                       kind=fs.Integer)
        self.output("t_out", "s", "Current time")
        self.output("helper", None, "pid of the forked helper (0: none)", kind=fs.Integer,
                    start=0)

    def make_core(self):
        # once per instance (a provisional core is also made in initialisation mode)
        if self.fork_seconds > 0.0 and not getattr(self, "_helper", 0):
            self._helper = self._fork_helper(float(self.fork_seconds), int(self.leave))
        return {"helper": getattr(self, "_helper", 0)}

    @staticmethod
    def _fork_helper(seconds, leave):
        """The pid of a helper that sleeps ``seconds`` holding what it inherited."""
        import time

        reader, writer = os.pipe()
        pid = os.fork()
        if pid == 0:
            try:
                if leave == 2 and os.fork() != 0:
                    os._exit(0)  # the middle process: gone at once
                if leave:
                    os.setsid()
                os.write(writer, str(os.getpid()).encode() + b"\n")
                time.sleep(seconds)
            finally:
                os._exit(0)
        os.close(writer)
        with os.fdopen(reader, "rb") as stream:
            helper = int(stream.readline())
        if leave == 2:
            os.waitpid(pid, 0)  # the middle process
        return helper

    def advance(self, t, h):
        n = int(self.stdout_bytes)
        if n > 0:
            chunk = (b"FMU output " * (n // 11 + 1))[:n]
            os.write(1, chunk)
            os.write(2, chunk)
            print("a line printed by the FMU at t =", t)
        if self.message:
            from pythonfmu.enums import Fmi2Status

            self.log(str(self.message), Fmi2Status.warning)
        count = int(self.log_count)
        if count > 0:
            from pythonfmu.enums import Fmi2Status

            for i in range(count - 1):
                self.log(f"chatter {i} at t = {t}", Fmi2Status.ok)
            self.log(f"the last of {count} messages at t = {t}", Fmi2Status.warning)
        if 0.0 <= self.fail_time <= t + 1e-12:
            raise RuntimeError(str(self.message))
        if 0.0 <= self.garbage_time <= t + 1e-12:
            for fd in _pipes():
                try:
                    os.write(fd, b"\xff\xfe garbage from the FMU " * 8)
                except OSError:
                    pass

    def publish(self):
        self.t_out = self.time
        self.helper = self.core["helper"] if self.core else 0
