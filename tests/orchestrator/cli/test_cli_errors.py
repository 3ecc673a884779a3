"""One test per class of bad input: exit code 2 and a one-line message naming the
manifest, the key and the culprit (cli.main + capsys, no subprocess)."""

import re

import pytest

from agv_cosim import cli


def _line_of(text, needle, last=False):
    """The line (from 1) of ``text`` where ``needle`` (its last occurrence) begins."""
    return text[:text.rindex(needle) if last else text.index(needle)].count("\n") + 1


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
    path = chain()
    # the line of the key: the edited line, or the [[connections]] header above it
    # for a problem of the whole connection
    number = _line_of(path.read_text(), old) - (1 if key.endswith("]") else 0)
    if "already connected" in culprit:  # the second connection to the input is named
        number = _line_of(path.read_text(), new, last=True)
    _edit(path, old, new)
    line = _fail(capsys, ["validate", str(path)])
    assert line.startswith(f"agv-cosim: error: {path}:{number}: {key}: "), line
    assert culprit in line


def test_broken_fmu(chain, capsys, tmp_path):
    broken = tmp_path / "Broken.fmu"
    broken.write_bytes(b"not a zip file")
    path = chain()
    path.write_text(re.sub(r'fmu = "[^"]*AgvTestIntegrator.fmu"', f'fmu = "{broken}"',
                           path.read_text()))
    line = _fail(capsys, ["validate", str(path)])
    number = _line_of(path.read_text(), f'fmu = "{broken}"')
    assert f"{path}:{number}: components.int.fmu: broken FMU (not a zip archive)" in line


def test_unknown_variant(chain, capsys):
    path = chain(extra='[variants.fast.components.gain]\nparameters = { k = 9.0 }\n')
    line = _fail(capsys, ["run", str(path), "--variant", "slow", "--quiet"])
    assert f"{path}: variants: unknown variant 'slow' (known: fast)" in line


def test_sweep_over_non_parameter(chain, capsys):
    path = chain(extra='[sweep]\n"gain.y" = [1.0, 2.0]\n')
    line = _fail(capsys, ["validate", str(path)])
    number = _line_of(path.read_text(), '"gain.y" =')
    assert f"{path}:{number}: sweep.gain.y: 'gain.y' is an output, not a parameter" in line


def test_algebraic_loop_named(chain, capsys):
    # gain2.y feeds back into gain.u: src.y no longer drives gain; gain -> gain2 -> gain
    path = _edit(chain(), 'from = "src.y"\nto = "gain.u"', 'from = "gain2.y"\nto = "gain.u"')
    path = _edit(path, 'from = "gain2.y"\nto = "int.u"', 'from = "src.y"\nto = "int.u"')
    line = _fail(capsys, ["validate", str(path)])
    assert f"{path}:{_line_of(path.read_text(), '[[connections]]')}: connections: " \
        "algebraic loop" in line
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


# the chain manifest (conftest.CHAIN): [simulation] on line 3, stop 5, step 6,
# [components.gain] 11 with its parameters on 13, [[connections]] on 19, 22 and 25
@pytest.mark.parametrize("old, new, message", [
    ("[simulation]", "[simulaton]",
     "3: simulaton: unknown section 'simulaton' (did you mean 'simulation'?)"),
    ("stop = 1.0", "stp = 1.0", "5: simulation.stp: unknown key 'stp' (did you mean 'stop'?)"),
    ("k = 3.0", "kk = 3.0", "13: components.gain.parameters.kk: unknown parameter 'kk' of "
     "gain (AgvTestGain) (did you mean 'k'?)"),
    ('from = "src.y"', 'from = "src.yy"', "20: connections[0].from: unknown variable "
     "'src.yy' of AgvTestSource (did you mean 'y'?)"),
    ('to = "int.u"', 'to = "intt.u"', "27: connections[2].to: unknown component 'intt' (did "
     "you mean 'int'?)"),
    ('algorithm = "gauss-seidel"', 'algorithm = "gauss-siedel"', "7: simulation.algorithm: "
     "'gauss-siedel' is not one of gauss-seidel, jacobi (did you mean 'gauss-seidel'?)"),
])
def test_misspellings_name_the_closest_valid_name_and_the_line(chain, capsys, old, new,
                                                               message):
    path = _edit(chain(), old, new)
    assert _fail(capsys, ["validate", str(path)]) == f"agv-cosim: error: {path}:{message}"


def test_every_problem_of_the_schema_is_reported_once_in_line_order(chain, capsys):
    path = _edit(chain(), 'step = 0.1\nalgorithm = "gauss-seidel"',
                 'step = -0.1\nalgorithm = "fast"')
    path = _edit(path, "stop = 1.0", "stp = 1.0")
    path = _edit(path, 'from = "gain.y"', 'frm = "gain.y"')
    path.write_text(path.read_text() + "[plots]\ndpi = 1.5\n")
    assert cli.main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"agv-cosim: error: {path}:{line}" for line in (
        "5: simulation.stp: unknown key 'stp' (did you mean 'stop'?)",
        "6: simulation.step: -0.1 must be > 0",
        "7: simulation.algorithm: 'fast' is not one of gauss-seidel, jacobi",
        "23: connections[1].frm: unknown key 'frm' (did you mean 'from'?)",
        "29: plots.dpi: 1.5 is not an integer",
    )]


def test_many_problems_are_capped(chain, capsys):
    path = chain(extra="".join(f"[components.c{i}]\nfmu = {i}\n" for i in range(25)))
    assert cli.main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 20
    assert err[0] == f"agv-cosim: error: {path}:29: components.c0.fmu: 0 is not a string"
    assert err[-1] == f"agv-cosim: error: {path}: 6 more problem(s) not shown"


@pytest.mark.parametrize("command", [[], ["build"], ["examples"], ["run"], ["validate"],
                                     ["report"], ["list"], ["export-ssp"]])
def test_help_shows_no_rest_markup(capsys, command):
    with pytest.raises(SystemExit) as stop:
        cli.main([*command, "--help"])
    assert stop.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: agv-cosim {command[0] if command else ''}".rstrip())
    assert "``" not in out


def test_an_argument_left_over_is_the_subcommands_error(capsys):
    """``run M --set x 2.5`` (a value given apart from its name): run's usage and error,
    not the top-level usage."""
    with pytest.raises(SystemExit) as stop:
        cli.main(["run", "m.toml", "--set", "x", "2.5"])
    assert stop.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("usage: agv-cosim run ")
    assert err.strip().splitlines()[-1] == ("agv-cosim run: error: unrecognized arguments: "
                                            "2.5")
