"""The interop tests' fixture: the Reference FMUs' ``fmusim`` host (fmusim_host.py)."""

import pytest

from fmusim_host import build_fmusim


@pytest.fixture(scope="session")
def fmusim(tmp_path_factory):
    """The Reference FMUs' fmusim, built once per worker (fmusim_host.py)."""
    return build_fmusim(tmp_path_factory.mktemp("fmusim"))
