"""The sample classification of benchmarks/profile_split.py and the source transform of
benchmarks/bench_compiled_cores.py (pure functions; perf and the compilers not needed)."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))

from bench_compiled_cores import mypy_config, typed_properties  # noqa: E402
from profile_split import classify  # noqa: E402

PY = "/root/.pyenv/versions/3.11.7/lib/libpython3.11.so.1.0"
EXE = "/root/.pyenv/versions/3.11.7/bin/python3.11"
BRIDGE = "/tmp/agv_cosim_act_x/binaries/linux64/AgvSteeringA.bridge.so"
LOADER = "/tmp/agv_cosim_act_x/binaries/linux64/AgvSteeringA.so"
FFI = "/usr/lib/x86_64-linux-gnu/libffi.so.8.1.2"
CTYPES = "/x/lib-dynload/_ctypes.cpython-311-x86_64-linux-gnu.so"
FMICALL = "/root/.cache/agv-cosim/_fmicall-b5f0.cpython-311-x86_64-linux-gnu.so"
LIBC = "/usr/lib/x86_64-linux-gnu/libc.so.6"
EVAL = ("_PyEval_EvalFrameDefault", PY)
ROOT = [EVAL, ("Py_RunMain", PY), ("main", EXE), ("__libc_start_call_main", LIBC)]
VIA_CTYPES = [("?", LOADER), ("ffi_call", FFI), ("_ctypes_callproc", CTYPES), *ROOT]
VIA_C = [("?", LOADER), ("run_program", FMICALL), ("run_stretch", FMICALL), *ROOT]


def test_each_part_of_the_stack_gets_its_category():
    fmu_python = [("float_add", PY), EVAL, ("_PyFunction_Vectorcall", PY), ("?", BRIDGE)]
    assert classify(fmu_python + VIA_CTYPES) == "FMUs' own Python (cores and adapter)"
    assert classify(fmu_python + VIA_C) == "FMUs' own Python (cores and adapter)"
    lookup = [("_PyType_Lookup", PY), ("PyObject_SetAttr", PY), ("?", BRIDGE)]
    assert classify(lookup + VIA_C) == "libpython for the bridge"
    assert classify([("memcpy", LIBC), ("?", BRIDGE)] + VIA_C) == "bridge/loader C"
    assert classify([("?", BRIDGE)] + VIA_CTYPES) == "bridge/loader C"
    assert classify(VIA_CTYPES[1:]) == "FMI call mechanism (ctypes/libffi)"
    assert classify([("PyLong_AsLong", PY)] + VIA_CTYPES[2:]) == \
        "FMI call mechanism (ctypes/libffi)"
    assert classify([("PySequence_SetItem", PY)] + VIA_C[1:]) == "compiled path (_fmicall)"
    assert classify([("tupledealloc", PY)] + ROOT) == "master's own Python"
    gc = [("visit_decref", PY), ("gc_collect_main", PY), ("_PyObject_GC_New", PY)]
    assert classify(gc + ROOT) == "GC"
    assert classify(gc + fmu_python + VIA_C) == "GC"


def test_a_stack_that_stops_early_is_counted_apart():
    assert classify([("_PyType_Lookup", PY), ("?", BRIDGE)]) == "stack not unwound"
    assert classify([]) == "stack not unwound"


def test_typed_properties_annotates_bare_getters_only():
    source = ('"""doc"""\nfrom __future__ import annotations\nimport math\n\n\n'
              "class A:\n    @property\n    def h(self):\n        return 1\n\n"
              "    @property\n    def k(self) -> int:\n        return 2\n\n"
              "    def m(self):\n        return math.pi\n")
    out = typed_properties(source)
    assert "    def h(self) -> Any:\n" in out
    assert "    def k(self) -> int:\n" in out and "    def m(self):\n" in out
    assert out.index("from __future__") < out.index("from typing import Any\n") \
        < out.index("import math")
    assert typed_properties("import math\n") == "import math\n"


def test_mypy_config_checks_only_the_compiled_modules_unless_asked():
    package = Path("/w/agv_core_abc")
    text = mypy_config(package, ["sensors/sensors.py"], check_all=False)
    assert "ignore_errors = True\n" in text
    assert "[mypy-agv_core_abc.sensors.sensors]\nignore_errors = False\n" in text
    assert "ignore_errors" not in mypy_config(package, ["sensors/sensors.py"], True)
