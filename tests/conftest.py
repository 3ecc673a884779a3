"""Shared fixtures: the component FMUs, built once per test session into a temp folder."""

import pytest

from agv_cosim.build import build_fmus, default_components_dir, slave_scripts


@pytest.fixture(scope="session")
def component_fmus(tmp_path_factory):
    """Build every component FMU into a session temp folder; map script stem -> FMU path."""
    out = tmp_path_factory.mktemp("fmus")
    results = build_fmus(out, slave_scripts(default_components_dir()))
    return {result.script.stem: result.fmu for result in results}
