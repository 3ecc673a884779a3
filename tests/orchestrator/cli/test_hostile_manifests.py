"""Hostile round three, manifests: only regular files of bounded size are read (a FIFO
or a device cannot hang us or fill memory), nesting is bounded, and every such manifest
is one line, exit 2."""

import os
import threading

import pytest

from agv_cosim import cli
from agv_cosim.manifest import load as manifest
from agv_cosim.system import feedthrough_order


def _fail(capsys, argv):
    code = cli.main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert len(err) == 1 and err[0].startswith("agv-cosim: error: "), err
    return err[0]


def test_a_fifo_is_refused_without_blocking(tmp_path, capsys):
    """Nothing writes into the FIFO: reading it would block for ever."""
    fifo = tmp_path / "m.toml"
    os.mkfifo(fifo)
    done = []
    thread = threading.Thread(target=lambda: done.append(
        _fail(capsys, ["validate", str(fifo)])), daemon=True)
    thread.start()
    thread.join(60)
    if thread.is_alive():  # unblock the reader so the test process can end
        with open(fifo, "w"):
            pass
        pytest.fail("reading a FIFO manifest blocked")
    assert done == [f"agv-cosim: error: {fifo}: file: is a FIFO, not a regular file"]


@pytest.mark.parametrize("device", ["/dev/zero", "/dev/null"])
def test_a_device_is_refused(capsys, device):
    if not os.path.exists(device):
        pytest.skip(f"no {device}")
    assert _fail(capsys, ["validate", device]) == \
        f"agv-cosim: error: {device}: file: is a device, not a regular file"


def test_a_folder_and_a_huge_file_are_refused(tmp_path, capsys, monkeypatch):
    assert _fail(capsys, ["validate", str(tmp_path)]) == \
        f"agv-cosim: error: {tmp_path}: file: is a folder, not a regular file"
    big = tmp_path / "big.toml"
    with open(big, "wb") as stream:
        stream.truncate(manifest.MAX_MANIFEST_BYTES + 1)  # sparse: no disk used
    assert _fail(capsys, ["validate", str(big)]) == (
        f"agv-cosim: error: {big}: file: is {manifest.MAX_MANIFEST_BYTES + 1} bytes; at "
        f"most {manifest.MAX_MANIFEST_BYTES} are read")


@pytest.mark.parametrize("depth", [40, 5000])
def test_deep_nesting_is_one_line(tmp_path, capsys, depth):
    """Arrays 40 deep (parsed, then refused) and 5000 deep (the TOML parser's own
    recursion limit): both one line, exit 2."""
    path = tmp_path / "deep.toml"
    path.write_text("x = " + "[" * depth + "]" * depth + "\n")
    line = _fail(capsys, ["validate", str(path)])
    assert line.startswith(f"agv-cosim: error: {path}: toml: ")
    assert f"nested more than {manifest.MAX_DEPTH} levels deep" in line
    tables = tmp_path / "tables.toml"
    tables.write_text("x = " + "{ a = " * 60 + "1" + " }" * 60 + "\n")
    assert "nested more than" in _fail(capsys, ["validate", str(tables)])


def test_deep_set_value_is_one_line(chain, capsys):
    line = _fail(capsys, ["validate", str(chain()), "--no-init", "--set",
                          "gain.k=" + "[" * 5000 + "]" * 5000])
    assert ": --set: gain.k: nested more than" in line


def test_the_order_of_many_independent_components_is_the_manifest_order():
    """3000 components, none feeding another through a feedthrough output: the
    Gauss-Seidel order is the manifest order (ties keep it)."""
    from agv_cosim.system.model import ModelInfo

    models = {f"c{i}": ModelInfo(path=None, sha256="", model_name="m", identifier="m",
                                 guid="", description="") for i in range(3000)}
    names = list(models)[::-1]  # a manifest order that is not sorted by name
    models = {name: models[name] for name in names}
    assert feedthrough_order(models, []) == names


def test_a_fifo_as_ssp_package_or_time_table_is_refused(chain, tmp_path, capsys):
    """An .ssp package and a time table named by a manifest are read as regular files
    only: a FIFO (nothing writes into it) is one line, not a hang."""
    package = tmp_path / "p.ssp"
    os.mkfifo(package)
    assert _fail(capsys, ["validate", str(package)]) == \
        f"agv-cosim: error: {package}: file: not a regular file or a folder"
    table = tmp_path / "in.csv"
    os.mkfifo(table)
    path = chain()
    path.write_text(path.read_text().replace(
        "[components.src]\n", f'[components.tab]\ntable = "{table}"\n[components.src]\n'))
    line = _fail(capsys, ["validate", str(path), "--no-init"])
    number = path.read_text().splitlines().index(f'table = "{table}"') + 1
    assert line == (f"agv-cosim: error: {path}:{number}: components.tab.table: '{table}' "
                    "is not a regular file")
