"""The problems the system check finds (after the schema stage: parameters, sweep,
connections, events, signals) are reported all at once, one line each, capped at
``errors.MAX_REPORTED`` lines, as the schema's are."""

from agv_cosim import cli
from agv_cosim.errors import MAX_REPORTED


def _edit(path, *pairs):
    text = path.read_text()
    for old, new in pairs:
        assert text.count(old) == 1, old
        text = text.replace(old, new)
    path.write_text(text)
    return path


def test_every_problem_of_the_system_at_once(chain, capsys):
    path = _edit(chain(), ("k = 3.0", "kk = 3.0"),
                 ("offset = 1.0, slope = 2.0", 'offset = 1.0, slope = "steep"'),
                 ('from = "gain2.y"\nto = "int.u"', 'from = "gain2.y"\nto = "int.uu"'))
    assert cli.main(["validate", str(path), "--no-init"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert [line.split(": ", 4)[3] for line in err] == [
        "components.src.parameters.slope", "components.gain.parameters.kk",
        "connections[2].to"], err
    assert "unknown parameter 'kk'" in err[1] and "did you mean 'k'" in err[1]
    assert "'src.slope' is Real, got 'steep'" in err[0]
    assert "unknown variable 'int.uu'" in err[2]


def test_system_problems_are_capped(chain, capsys):
    many = ", ".join(f"p{i} = 1.0" for i in range(MAX_REPORTED + 5))
    path = _edit(chain(), ("k = 3.0", many))
    assert cli.main(["run", str(path), "--no-init"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == MAX_REPORTED
    assert all("unknown parameter 'p" in line for line in err[:-1])
    assert err[-1] == f"agv-cosim: error: {path}: 6 more problem(s) not shown"


def test_every_connection_problem_at_once(chain, capsys):
    path = _edit(chain(), ('from = "src.y"', 'from = "src.yy"'),
                 ('to = "gain2.u"', 'to = "gain2.uu"'))
    assert cli.main(["validate", str(path), "--no-init"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert [line.split(": ", 4)[3] for line in err] == [
        "connections[0].from", "connections[1].to"], err
    assert "unknown variable 'src.yy'" in err[0]
    assert "unknown variable 'gain2.uu'" in err[1]


VARIANTS = """
[variants.slow.components.gain]
parameters = { k = 1.0 }
[variants.fast.components.gain]
parameters = { k = 9.0 }
[variants.fast.components.gain2]
parameters = { kk = 2.0 }
"""


def test_a_problem_of_every_variant_is_said_once_without_a_variant(chain, capsys):
    path = _edit(chain(extra=VARIANTS), ('to = "int.u"', 'to = "int.uu"'))
    assert cli.main(["validate", str(path), "--no-init"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2, err
    # the base's connection fails in both variants: once, naming no variant
    assert "connections[2].to: unknown variable 'int.uu'" in err[0]
    assert "variant" not in err[0]
    # a problem of one variant's own key is said once and names it
    assert "variants.fast.components.gain2.parameters.kk" in err[1]
    assert err[1].count("unknown parameter 'kk'") == 1


def test_each_problem_is_said_once(chain, fmus, capsys):
    # swap gives gain another interface: the base's parameter and both connections of
    # gain fail in its run only, found by two checks (parameters, then connections)
    variants = f"""
[variants.unit.components.gain]
parameters = {{ k = 1.0 }}
[variants.swap.components.gain]
fmu = "{fmus['agv_test_pair']}"
"""
    path = chain(extra=variants)
    assert cli.main(["validate", str(path), "--no-init"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == len(set(err)) == 3, err
    assert [line.split(": ", 5)[3:5] for line in err] == [
        ["components.gain.parameters.k", "variant 'swap'"],
        ["connections[0].to", "variant 'swap'"], ["connections[1].from", "variant 'swap'"]], err
