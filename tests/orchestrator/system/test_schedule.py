"""The Gauss-Seidel schedule (agv_cosim.system.feedthrough_order) on small graphs by hand."""

from types import SimpleNamespace

import pytest

from agv_cosim.manifest import Connection, ManifestError
from agv_cosim.system import feedthrough_order


def _model(**dependencies):
    """A stand-in for ModelInfo: output -> the inputs it depends on directly."""
    return SimpleNamespace(dependencies=dependencies)


def _conn(source, target):
    return Connection(tuple(source.split(".")), tuple(target.split(".")), "connections[0]")


def test_feedthrough_chain_is_ordered_and_ties_keep_the_manifest_order():
    # c feeds b through a feedthrough output, b feeds a; d and e are free: manifest order
    # d, a, e, b, c -> c before b before a, d and e where they become ready first
    models = {"d": _model(y=[]), "a": _model(y=["u"]), "e": _model(y=[]),
              "b": _model(y=["u"]), "c": _model(y=["u"])}
    conns = [_conn("c.y", "b.u"), _conn("b.y", "a.u"), _conn("d.y", "c.u")]
    assert feedthrough_order(models, conns) == ["d", "e", "c", "b", "a"]


def test_an_output_without_feedthrough_imposes_no_order():
    models = {"plant": _model(y=[]), "ctrl": _model(u=["e"])}
    conns = [_conn("plant.y", "ctrl.e"), _conn("ctrl.u", "plant.f")]
    assert feedthrough_order(models, conns) == ["ctrl", "plant"]


def test_algebraic_loop_is_named_from_its_smallest_variable():
    models = {"p": _model(y=["u"]), "q": _model(y=["u"])}
    conns = [_conn("q.y", "p.u"), _conn("p.y", "q.u")]
    with pytest.raises(ManifestError) as caught:
        feedthrough_order(models, conns, "m.toml")
    assert str(caught.value) == ("m.toml: connections: algebraic loop (a cycle of direct "
                                 "feedthrough): p.u -> p.y -> q.u -> q.y -> p.u")
