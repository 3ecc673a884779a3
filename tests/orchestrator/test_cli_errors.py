"""One test per class of bad input: exit code 2 and a one-line message naming the
manifest, the key and the culprit (cli.main + capsys, no subprocess)."""

import pytest

from agv_cosim import cli


def _fail(capsys, argv):
    code = cli.main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2
    errors = [line for line in err if line.startswith("agv-cosim: error: ")]
    assert len(errors) == 1, err
    assert "Traceback" not in "\n".join(err)
    return errors[0]


def _edit(path, old, new):
    text = path.read_text()
    assert old in text
    path.write_text(text.replace(old, new, 1))
    return path


@pytest.mark.parametrize("old, new, key, culprit", [
    ('from = "src.y"\nto = "gain.u"', 'from = "nope.y"\nto = "gain.u"',
     "connections[0].from", "unknown component 'nope'"),
    ('from = "src.y"\nto = "gain.u"', 'from = "src.zz"\nto = "gain.u"',
     "connections[0].from", "unknown variable 'src.zz'"),
    ("k = 3.0", "k = 3.0, kk = 1.0", "components.gain.parameters.kk",
     "unknown parameter 'kk'"),
    ('to = "gain.u"', 'to = "gain.y"', "connections[0].to", "'gain.y' is an output"),
    ('from = "src.y"', 'from = "gain2.u"', "connections[0].from", "'gain2.u' is an input"),
    ('to = "gain.u"', 'to = "gain.k"', "connections[0].to", "'gain.k' is a parameter"),
    ('from = "src.y"', 'from = "src.t_out"', "connections[0]", "unit mismatch"),
    ('from = "src.y"', 'from = "src.count"', "connections[0]", "type mismatch"),
    ("k = 3.0", 'k = "three"', "components.gain.parameters.k", "type mismatch"),
    ('to = "gain2.u"', 'to = "int.u"', "connections[2].to",
     "input 'int.u' is already connected by connections[1]"),
    ("step = 0.1", "step = 0.0", "simulation.step", "must be > 0"),
    ("step = 0.1", "step = -0.1", "simulation.step", "must be > 0"),
    ("stop = 1.0", "stop = 0.0", "simulation.stop", "must be > start"),
    ("AgvTestGain.fmu", "Missing.fmu", "components.gain.fmu", "FMU not found"),
])
def test_manifest_errors(chain, capsys, old, new, key, culprit):
    path = _edit(chain(), old, new)
    line = _fail(capsys, ["validate", str(path)])
    assert line.startswith(f"agv-cosim: error: {path}: {key}: "), line
    assert culprit in line


def test_broken_fmu(chain, capsys, tmp_path):
    broken = tmp_path / "Broken.fmu"
    broken.write_bytes(b"not a zip file")
    import re

    path = chain()
    path.write_text(re.sub(r'fmu = "[^"]*AgvTestIntegrator.fmu"', f'fmu = "{broken}"',
                           path.read_text()))
    line = _fail(capsys, ["validate", str(path)])
    assert f"{path}: components.int.fmu: broken FMU (not a zip archive)" in line


def test_unknown_variant(chain, capsys):
    path = chain(extra='[variants.fast.components.gain]\nparameters = { k = 9.0 }\n')
    line = _fail(capsys, ["run", str(path), "--variant", "slow", "--quiet"])
    assert f"{path}: variants: unknown variant 'slow' (known: fast)" in line


def test_sweep_over_non_parameter(chain, capsys):
    path = chain(extra='[sweep]\n"gain.y" = [1.0, 2.0]\n')
    line = _fail(capsys, ["validate", str(path)])
    assert f"{path}: sweep.gain.y: 'gain.y' is an output, not a parameter" in line


def test_algebraic_loop_named(chain, capsys):
    # gain2.y feeds back into gain.u: src.y no longer drives gain; gain -> gain2 -> gain
    path = _edit(chain(), 'from = "src.y"\nto = "gain.u"', 'from = "gain2.y"\nto = "gain.u"')
    path = _edit(path, 'from = "gain2.y"\nto = "int.u"', 'from = "src.y"\nto = "int.u"')
    line = _fail(capsys, ["validate", str(path)])
    assert f"{path}: connections: algebraic loop" in line
    assert "gain.u -> gain.y -> gain2.u -> gain2.y -> gain.u" in line


def test_unconnected_inputs_warn(chain, capsys):
    path = _edit(chain(), '[[connections]]\nfrom = "gain2.y"\nto = "int.u"\n', "")
    assert cli.main(["validate", str(path)]) == 0
    err = capsys.readouterr().err
    assert f"agv-cosim: warning: {path}: connections: unconnected inputs" in err
    assert "int.u" in err


def test_bad_set_and_debug_traceback(chain, capsys):
    path = chain()
    line = _fail(capsys, ["validate", str(path), "--set", "gain.nope=1.0"])
    assert f"{path}: --set: unknown parameter 'nope'" in line
    # --debug adds the traceback and changes nothing else: same line, same exit code
    assert cli.main(["validate", str(path), "--set", "gain.nope=1.0", "--debug"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" in err and "ManifestError" in err
    assert err.strip().splitlines()[-1] == line


def test_toml_syntax_error(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text("name = \n")
    line = _fail(capsys, ["validate", str(path)])
    assert line.startswith(f"agv-cosim: error: {path}: toml: ")
