"""The commands whose runs go through the workers (run, tune, fit) take --jobs, --dask and
--overwrite (run and tune --timeout too) as one declaration: the same type, default,
metavar and help in each; only --timeout's consequence differs, stated per command."""

import argparse

import pytest

from agv_cosim import cli

COMMANDS = ("run", "tune", "fit")
SHARED = ("--jobs", "--dask", "--overwrite")


def _options(command):
    """Option string -> its argparse action, of the subcommand ``command``."""
    parser = cli.make_parser().commands[command]
    return {s: a for a in parser._actions for s in a.option_strings}


def _declaration(action):
    return (action.option_strings, action.dest, action.type, action.default, action.const,
            action.nargs, action.metavar, action.required, action.choices, action.help,
            type(action))


@pytest.mark.parametrize("option", SHARED)
def test_the_worker_options_are_declared_alike(option):
    declarations = {c: _declaration(_options(c)[option]) for c in COMMANDS}
    assert declarations["tune"] == declarations["run"]
    assert declarations["fit"] == declarations["run"]


def test_timeout_alike_but_for_what_becomes_of_a_run_over_it():
    run, tune = _options("run")["--timeout"], _options("tune")["--timeout"]
    assert _declaration(run)[:-2] == _declaration(tune)[:-2]  # all but help and class
    assert run.type is tune.type is cli._timeout and run.default is None
    for action, consequence in ((run, "reported 'timed out', the others go on"),
                                (tune, "its candidate is infeasible")):
        assert action.help.startswith("wall-clock limit of each run: a run still going "
                                      "then is stopped and ")
        assert consequence in action.help
        assert action.help.endswith("(default: the manifest's [simulation] timeout, else "
                                    "no limit)")
    assert "--timeout" not in _options("fit")  # fit's runs have the manifest's limit


@pytest.mark.parametrize("command", COMMANDS)
def test_the_same_arguments_give_the_same_values(command):
    parser = cli.make_parser()
    head = [command, "m.toml", "--out", "out"]
    timed = ["--timeout", "2.5"] if command != "fit" else []
    given = parser.parse_args([*head, "--jobs", "3", "--dask", "tcp://h:8786",
                               "--overwrite", *timed])
    assert (given.jobs, given.dask, given.overwrite) == (3, "tcp://h:8786", True)
    default = parser.parse_args(head)
    assert (default.jobs, default.dask, default.overwrite) == (None, None, False)
    if timed:
        assert (given.timeout, default.timeout) == (2.5, None)


@pytest.mark.parametrize("command", COMMANDS)
def test_jobs_must_be_an_integer_in_each(command, capsys):
    with pytest.raises(SystemExit) as stop:
        cli.make_parser().parse_args([command, "m.toml", "--out", "out", "--jobs", "two"])
    assert stop.value.code == 2
    assert "argument --jobs: invalid int value: 'two'" in capsys.readouterr().err


def test_a_drifted_declaration_is_caught(monkeypatch):
    """The comparison sees a help text that differs in one command."""
    add = argparse.ArgumentParser.add_argument

    def drift(self, *names, **kwargs):
        if names == ("--dask",) and self.prog.endswith(" fit"):
            kwargs["help"] = "run on a Dask cluster"
        return add(self, *names, **kwargs)

    monkeypatch.setattr(argparse.ArgumentParser, "add_argument", drift)
    with pytest.raises(AssertionError):
        test_the_worker_options_are_declared_alike("--dask")
