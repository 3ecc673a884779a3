"""Hostile round three, Dask without a cluster: the worker's FMU cache is private and
checked at every use, and an address where no Dask scheduler answers is one line
within the connect timeout (the cluster cases are in test_dask.py, slow)."""

import hashlib
import os
import socket
import threading
import time

import pytest

from agv_cosim.errors import ClusterError, WorkerUnfit
from agv_cosim.workers import distributed
from agv_cosim.workers.distributed import cached_fmu, connect


def _blob(text=b"the FMU the client validated"):
    return text, hashlib.sha256(text).hexdigest()


def test_a_planted_cached_fmu_is_replaced_before_use(tmp_path):
    """A file with the expected name but other bytes (planted, or changed since) is
    replaced by the bytes the client sent; a link planted there too, its target left."""
    blob, sha = _blob()
    path = tmp_path / f"{sha}.fmu"
    path.write_bytes(b"y = 2 t")
    assert cached_fmu(sha, blob, tmp_path).read_bytes() == blob
    path.unlink()
    target = tmp_path / "elsewhere.fmu"
    target.write_bytes(blob)  # even the right bytes: a link is not our file
    path.symlink_to(target)
    assert cached_fmu(sha, blob, tmp_path) == path
    assert not path.is_symlink() and path.read_bytes() == blob
    assert target.read_bytes() == blob
    path.write_bytes(b"changed after the first use")  # checked at every use
    assert cached_fmu(sha, blob, tmp_path).read_bytes() == blob


@pytest.mark.parametrize("kind", ["world-writable", "group-writable", "link"])
def test_a_cache_folder_others_can_write_is_refused(tmp_path, monkeypatch, kind):
    monkeypatch.setattr(distributed.tempfile, "gettempdir", lambda: str(tmp_path))
    folder = tmp_path / f"agv-cosim-dask-fmus-{os.getuid()}"
    if kind == "link":
        (tmp_path / "real").mkdir(mode=0o700)
        folder.symlink_to(tmp_path / "real")
    else:
        folder.mkdir()
        os.chmod(folder, 0o777 if kind == "world-writable" else 0o770)
    with pytest.raises(WorkerUnfit, match="refusing to run FMUs from it"):
        distributed._fmu_cache()


def test_the_cache_folder_is_made_private(tmp_path, monkeypatch):
    monkeypatch.setattr(distributed.tempfile, "gettempdir", lambda: str(tmp_path))
    old = os.umask(0)
    try:
        folder = distributed._fmu_cache()
    finally:
        os.umask(old)
    assert (folder.stat().st_mode & 0o777) == 0o700


def _server(answer):
    """A TCP server on localhost that accepts and then says nothing (``answer`` None)
    or answers every request with ``answer``; returns (address, stop)."""
    listener = socket.socket()
    listener.bind(("127.0.0.1", 0))
    listener.listen(8)
    listener.settimeout(0.2)
    stopped = threading.Event()
    held = []

    def serve():
        while not stopped.is_set():
            try:
                conn, _ = listener.accept()
            except OSError:
                continue
            held.append(conn)
            if answer is not None:
                try:
                    conn.settimeout(2.0)
                    conn.recv(65536)
                    conn.sendall(answer)
                except OSError:
                    pass

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()

    def stop():
        stopped.set()
        thread.join(5)
        for conn in held:
            conn.close()
        listener.close()

    return f"tcp://127.0.0.1:{listener.getsockname()[1]}", stop


@pytest.mark.parametrize("answer", [None, b"HTTP/1.0 200 OK\r\nContent-Type: text/html"
                                          b"\r\n\r\n<html>not dask</html>\n"])
def test_an_address_where_no_scheduler_answers_is_one_line(answer):
    """A silent TCP server and an HTTP server: ClusterError naming the address within
    the timeout and a margin (distributed alone waited without end)."""
    address, stop = _server(answer)
    try:
        begin = time.monotonic()
        with pytest.raises(ClusterError) as error:
            connect(address, timeout=1.0)
        assert time.monotonic() - begin < 60
    finally:
        stop()
    text = str(error.value)
    assert "\n" not in text and address in text
    assert text.startswith(f"--dask: cannot reach the scheduler at {address}") or \
        text.startswith(f"--dask: {address} did not answer as a Dask scheduler")
