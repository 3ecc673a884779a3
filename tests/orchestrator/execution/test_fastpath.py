"""The generated per-step functions (agv_cosim.execution.fastpath) against the reference
loops (agv_cosim.execution.algorithm): the same rows bit for bit, their source
inspectable, and the private ctypes names they use pinned."""

import ctypes
import gc
import inspect
import linecache

import pytest

from agv_cosim.execution import RowObserver, fastpath, simulate
from agv_cosim.execution.instance import FmuInstance
from agv_cosim.execution.units import c_function
from agv_cosim.pipeline import prepare

#: Every path of the per-step code: a loop closed through an output without direct
#: feedthrough (the integrator is read first, once), feedthrough chains, a set whose
#: values are one source's consecutive outputs (q's inputs, from p), Integer, Boolean
#: and String inputs set by events, a time table driving a Real input.
SYSTEM = """
name = "paths"
[simulation]
stop = 2.0
step = 0.05
algorithm = "{algorithm}"
[components.src]
fmu = "{fmus[agv_test_source]}"
parameters = {{ offset = 1.0, slope = 2.0 }}
[components.gain]
fmu = "{fmus[agv_test_gain]}"
parameters = {{ k = -0.5 }}
[components.int]
fmu = "{fmus[agv_test_integrator]}"
parameters = {{ y0 = 1.0 }}
[components.p]
fmu = "{fmus[agv_test_pair]}"
parameters = {{ n = 3 }}
[components.q]
fmu = "{fmus[agv_test_pair]}"
[components.types]
fmu = "{fmus[agv_test_types]}"
[components.replay]
table = "{table}"
[[connections]]
from = "int.y"
to = "gain.u"
[[connections]]
from = "gain.y"
to = "int.u"
[[connections]]
from = "src.y"
to = "p.u1"
[[connections]]
from = "gain.y"
to = "p.u2"
[[connections]]
from = "p.y1"
to = "q.u1"
[[connections]]
from = "p.y2"
to = "q.u2"
[[connections]]
from = "replay.a"
to = "types.ri"
[events.change]
at = 0.5
set = {{ "types.ii" = 42, "types.bi" = true, "types.si" = "x, \\"y\\"" }}
[events.later]
at = 1.25
set = {{ "types.ii" = -3 }}
[record]
interval = 0.1
"""

STOP = """
name = "stop"
[simulation]
stop = 1.0
step = 0.1
algorithm = "{algorithm}"
[components.d]
fmu = "{fmus[agv_test_discard]}"
parameters = {{ discard_time = 0.3 }}
[components.src]
fmu = "{fmus[agv_test_source]}"
[components.gain]
fmu = "{fmus[agv_test_gain]}"
[[connections]]
from = "src.y"
to = "gain.u"
"""


def _manifest(tmp_path, text, fmus, algorithm):
    table = tmp_path / "replay.csv"
    table.write_text("time,a\n0,0\n1,4\n2,-1\n")
    path = tmp_path / f"{algorithm}.toml"
    path.write_text(text.format(algorithm=algorithm, fmus=fmus, table=table))
    return path


def _rows(job, fast):
    rows = []
    outcome = simulate(job.plan, [RowObserver(lambda row: rows.append(list(row)))],
                       fast=fast)
    return rows, outcome


@pytest.mark.slow  # seconds: builds the test FMUs
@pytest.mark.parametrize("text", [SYSTEM, STOP], ids=["paths", "stop"])
@pytest.mark.parametrize("algorithm", ["gauss-seidel", "jacobi"])
def test_fast_path_records_the_reference_rows_bit_for_bit(fmus, tmp_path, text, algorithm):
    _, jobs, _ = prepare(_manifest(tmp_path, text, fmus, algorithm))
    (job,) = jobs
    reference, ended = _rows(job, fast=False)
    fast, ended_fast = _rows(job, fast=True)
    assert len(reference) > 3
    assert [[v.hex() if isinstance(v, float) else v for v in row] for row in fast] == \
        [[v.hex() if isinstance(v, float) else v for v in row] for row in reference]
    assert ended_fast == ended
    if text is STOP:
        assert ended.ended_by.startswith("d requested stop")
    else:  # the events and the loop did show in the values
        record = job.plan.record
        io = [row[1 + record.index("types.io")] for row in reference]
        assert io[0] == 0 and 42 in io and io[-1] == -3
        assert len({row[1 + record.index("q.y2")] for row in reference}) > 3


def test_generated_source_is_inspectable_while_the_function_lives():
    buf = (ctypes.c_double * 2)(1.0, 2.0)
    code = fastpath.Code(track=[0.0, 0.0, 0.0])
    code.line(f"track[2] = {code.bind(buf, 'b')}[0] + t")
    function = code.function("probe", "t")
    function(3.0)
    source = inspect.getsource(function)
    assert "def probe(t):" in source and "track[2] = b1[0] + t" in source
    filename = function.__code__.co_filename
    assert filename.startswith("<agv_cosim fast path: probe #") and filename in linecache.cache
    del function, source
    gc.collect()
    assert filename not in linecache.cache


def test_a_failing_call_in_generated_code_shows_its_line():
    code = fastpath.Code()
    code.line("raise ValueError('from the generated line')")
    function = code.function("failing", "")
    with pytest.raises(ValueError) as info:
        function()
    frame = info.traceback[-1]
    assert "raise ValueError('from the generated line')" in str(frame.statement)


def test_the_private_ctypes_bases_it_relies_on():
    """fastpath uses ctypes._CFuncPtr, _Pointer and _SimpleCData: what they must be."""
    assert issubclass(ctypes.POINTER(ctypes.c_double), ctypes._Pointer)
    assert issubclass(ctypes.c_double, ctypes._SimpleCData)
    assert issubclass(ctypes.c_uint, ctypes._SimpleCData)
    assert not issubclass(ctypes.c_double * 2, ctypes._SimpleCData)
    assert issubclass(ctypes.CFUNCTYPE(ctypes.c_int), ctypes._CFuncPtr)
    libc = ctypes.CDLL(None)
    assert isinstance(libc.abs, ctypes._CFuncPtr)


@pytest.mark.slow  # builds the test FMUs
def test_fmpy_declares_the_library_functions_it_calls(fmus):
    """units.c_function takes fmpy's declared C function (``slave.dll.<name>``, argtypes
    set by fmpy), or fmpy's wrapper when a call logger is set."""
    from agv_cosim.system import read_model

    instance = FmuInstance(read_model(fmus["agv_test_gain"]), "gain")
    try:
        slave = instance.slave
        for name in ("fmi2GetReal", "fmi2SetReal", "fmi2DoStep", "fmi2GetInteger"):
            function = c_function(slave, name)
            assert isinstance(function, ctypes._CFuncPtr) and function.argtypes, name
            assert function is getattr(slave.dll, name)
        bare, args = fastpath.bare_call(c_function(slave, "fmi2DoStep"),
                                        (slave.component, 0.0, 0.1, 1))
        assert not bare.argtypes and len(args) == 4
        slave.fmiCallLogger = lambda message: None
        assert c_function(slave, "fmi2GetReal") == slave.fmi2GetReal
    finally:
        instance.close()


@pytest.mark.slow  # builds the test FMUs
def test_a_closed_instance_leaves_nothing_on_sys_path(fmus):
    """pythonfmu puts the FMU's resources folder on sys.path; close takes it off."""
    import sys

    from agv_cosim.system import read_model

    before = list(sys.path)
    instance = FmuInstance(read_model(fmus["agv_test_gain"]), "gain")
    folder = instance.unzip_dir
    added = [p for p in sys.path if p not in before]
    instance.close()
    assert added and all(p.startswith(folder) for p in added)
    assert sys.path == before
