"""The orchestrator tests' manifest writer (the test FMUs, ``fmus``: tests/conftest.py)."""

import pytest
from dask_cluster import cluster  # noqa: F401 - the Dask cluster fixture (workers/, fitting/)

CHAIN = """
name = "chain"
[simulation]
start = 0.0
stop = {stop}
step = {step}
algorithm = "{algorithm}"
[components.src]
fmu = "{src}"
parameters = {{ offset = 1.0, slope = 2.0 }}
[components.gain]
fmu = "{gain}"
parameters = {{ k = 3.0 }}
[components.gain2]
fmu = "{gain}"
parameters = {{ k = 0.5 }}
[components.int]
fmu = "{integ}"
[[connections]]
from = "src.y"
to = "gain.u"
[[connections]]
from = "gain.y"
to = "gain2.u"
[[connections]]
from = "gain2.y"
to = "int.u"
"""


@pytest.fixture
def chain(fmus, tmp_path):
    """Write the source -> gain -> gain2 -> integrator manifest; returns a writer."""

    def write(algorithm="gauss-seidel", stop=1.0, step=0.1, extra="", name="chain.toml"):
        text = CHAIN.format(stop=stop, step=step, algorithm=algorithm,
                            src=fmus["agv_test_source"], gain=fmus["agv_test_gain"],
                            integ=fmus["agv_test_integrator"]) + extra
        path = tmp_path / name
        path.write_text(text)
        return path

    return write
