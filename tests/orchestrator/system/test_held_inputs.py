"""``held``: inputs a manifest leaves unconnected on purpose. They are held at their
start values as any unconnected input, without the warning; a name that is not an input
is refused in one line; ``run --quiet`` prints no warning at all."""

import pytest

from agv_cosim import cli

#: the chain without its src -> gain connection: gain.u is unconnected
UNWIRED = ('[[connections]]\nfrom = "src.y"\nto = "gain.u"\n', "")


def _unwired(chain, held=None):
    path = chain()
    text = path.read_text().replace(*UNWIRED)
    if held is not None:
        text = text.replace('name = "chain"\n', f'name = "chain"\nheld = {held}\n')
    path.write_text(text)
    return path


def test_unconnected_input_warns(chain, capsys):
    assert cli.main(["validate", "--no-init", str(_unwired(chain))]) == 0
    err = capsys.readouterr().err
    assert "warning:" in err and "unconnected inputs (held at their start values): gain.u" \
        in err


def test_held_input_does_not_warn(chain, capsys, tmp_path):
    path = _unwired(chain, '["gain.u"]')
    assert cli.main(["validate", "--no-init", str(path)]) == 0
    assert capsys.readouterr().err == ""
    assert cli.main(["run", str(path), "--out", str(tmp_path / "out")]) == 0
    assert "warning" not in capsys.readouterr().err


@pytest.mark.parametrize("held, problem", [
    ('["gain.y"]', "held[0]: 'gain.y' is not an input of 'gain' (its inputs: u)"),
    ('["gain.u", "gian.u"]', "held[1]: 'gian.u': unknown component 'gian' (did you mean "
                             "'gain'?)"),
    ('["gain"]', "held[0]: 'gain' is not of the form"),
])
def test_held_name_that_is_not_an_input_is_refused(chain, capsys, held, problem):
    path = _unwired(chain, held)
    assert cli.main(["validate", "--no-init", str(path)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and problem in err and "Traceback" not in err


def test_quiet_run_prints_no_warning(chain, capsys, tmp_path):
    path = _unwired(chain)
    assert cli.main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and captured.out == ""


ROOT = __import__("pathlib").Path(__file__).resolve().parents[3]


@pytest.mark.skipif(not (ROOT / "fmus" / "AgvVehicle.fmu").is_file(),
                    reason="needs the built FMUs (make fmus)")
@pytest.mark.parametrize("manifest", sorted(p.name for p in (ROOT / "experiments")
                                            .glob("*.toml")))
def test_shipped_experiments_have_no_warning(manifest):
    # `make run` and every shipped manifest: the inputs they leave unconnected are held
    from agv_cosim.pipeline import prepare

    _, _, warnings = prepare(ROOT / "experiments" / manifest, None, [])
    assert warnings == []


@pytest.mark.skipif(not (ROOT / "fmus" / "AgvVehicle.fmu").is_file(),
                    reason="needs the built FMUs (make fmus)")
def test_held_input_of_a_variant_not_run_is_accepted(capsys, tmp_path):
    # experiments/baselines.toml holds the pose inputs of the laws that have them
    # (ctrl.x, ...); its state_feedback variant's ctrl has none: running that variant
    # alone is valid, and a name that no variant has is still refused
    manifest = str(ROOT / "experiments" / "baselines.toml")
    assert cli.main(["validate", "--no-init", manifest, "--variant", "state_feedback"]) == 0
    assert capsys.readouterr().err == ""
    text = (ROOT / "experiments" / "baselines.toml").read_text()
    assert '"ctrl.dv"]' in text
    typo = tmp_path / "baselines.toml"
    typo.write_text(text.replace('"ctrl.dv"]', '"ctrl.dw"]')
                    .replace('"../fmus/', f'"{ROOT}/fmus/'))
    assert cli.main(["validate", "--no-init", str(typo), "--variant", "state_feedback"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "held[6]: 'ctrl.dw' is not an input of 'ctrl'" in err
