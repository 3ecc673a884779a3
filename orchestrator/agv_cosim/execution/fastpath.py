"""The opt-in fast path: the per-step functions of one run generated as Python source.

The reference is the plain loop of :mod:`agv_cosim.execution.algorithm`: it visits the
units and their groups in loops. Here the same calls, in the same order, are written out
for the run's FMUs, one line per call: every function, argument and buffer is a closure
variable of the generated function (a fast local load), and the batched get/set calls
skip ctypes' per-call argument conversion (:func:`bare_call`). The same values reach
the same C functions in the same order, so both give bit-identical results
(tests/orchestrator/execution/test_fastpath.py runs both side by side).

Only made-up identifiers (``f0``, ``a1``, ``b2``) and integers go into the source text;
component, variable and function names stay data in the closure. The source of each
generated function is registered with :mod:`linecache` under the function's file name
(``<agv_cosim fast path: NAME #N>``): a traceback shows the line that ran, and
``inspect.getsource`` returns it.

Private ctypes names used (ctypes has no public ones for them), each pinned by
tests/orchestrator/execution/test_fastpath.py: ``ctypes._CFuncPtr`` (base of a library function),
``ctypes._Pointer`` (base of ``POINTER(T)``), ``ctypes._SimpleCData`` (base of
``c_double`` and the other scalars).
"""

import ctypes
import itertools
import linecache
import weakref
from collections.abc import Callable, Iterable
from math import isfinite
from typing import Any

from .units import FmuUnit, Group, Unit, check_finite, failed

__all__ = ["Code", "bare_call", "gauss_seidel_pass", "jacobi_get", "jacobi_set",
           "shared_values", "step_all"]

_NUMBERS = itertools.count(1)
#: The base class of every ctypes function pointer (ctypes names it privately only).
_FUNCTION_BASE: Any = ctypes._CFuncPtr  # type: ignore[attr-defined]


def _passed_as_is(value: Any) -> Any:
    """``value`` (a converted argument of :func:`bare_call`) in the form ctypes passes
    with the least work, the same bits reaching the C function.

    ctypes wraps every ctypes instance it is given in a new argument object at every
    call; a ``byref`` object (an address) and a small Python int pass without one. An
    array passes as the address of its first element, a pointer or ``c_void_p`` as the
    address it holds (the object at that address keeps the referent alive), an unsigned
    or int count below 2**31 as a Python int (a C int, which the x86-64 and AArch64
    calling conventions extend to the register). Anything else (the shared time and step
    ``c_double``, whose value changes between calls) is passed unchanged.
    """
    if isinstance(value, ctypes.Array):
        return ctypes.byref(value)
    if isinstance(value, (ctypes._Pointer, ctypes.c_void_p)):
        address = ctypes.cast(value, ctypes.c_void_p).value
        if not address:
            return value
        target = ctypes.c_char.from_address(address)
        target.keep = value  # type: ignore[attr-defined]  # the pointer lives as long
        return ctypes.byref(target)
    if isinstance(value, (ctypes.c_int, ctypes.c_uint, ctypes.c_size_t)) and \
            0 <= value.value < 2 ** 31:
        return int(value.value)
    return value


def bare_call(function: Any, args: tuple[Any, ...]) -> tuple[Any, tuple[Any, ...]]:
    """``(function, args)`` for a call without ctypes' per-call argument conversion.

    A library function with ``argtypes`` converts every argument at every call. The
    batched get/set calls always pass the same objects (component, value-reference
    array, count, value buffer), so they are converted once here: each argument becomes
    an instance of its declared type (arrays pass as the pointer they are), and the call
    goes through a pointer to the same C function that has no ``argtypes``. Anything
    else (fmpy's wrapper, an argument this cannot convert) is returned unchanged.
    """
    argtypes = getattr(function, "argtypes", None)
    if not isinstance(function, _FUNCTION_BASE) or not argtypes or \
            len(argtypes) != len(args):
        return function, args
    converted = []
    for argtype, value in zip(argtypes, args, strict=True):
        if isinstance(value, argtype):
            converted.append(value)
        elif isinstance(value, ctypes.Array) and isinstance(argtype, type) and \
                issubclass(argtype, ctypes._Pointer) and value._type_ is argtype._type_:
            converted.append(value)
        elif isinstance(argtype, type) and issubclass(argtype, ctypes._SimpleCData) and \
                not isinstance(value, (ctypes._SimpleCData, ctypes.Array, ctypes._Pointer)):
            converted.append(argtype(value))
        else:
            return function, args
    converted = [_passed_as_is(value) for value in converted]
    # PYFUNCTYPE: the GIL stays held during the call (an FMU whose slave is Python takes
    # it again at once; releasing and re-taking it cost more than the call itself)
    restype: Any = function.restype
    address = ctypes.cast(function, ctypes.c_void_p).value
    if not address:
        return function, args
    bare: Any = ctypes.PYFUNCTYPE(restype)(address)
    bare.argtypes = None
    bare.restype = restype
    bare.keep = function  # the library's entry stays referenced
    return bare, tuple(converted)


def shared_values(in_val: Any, links: Iterable[tuple[int, Any, int]]) -> Any:
    """A pointer into the source buffer whose consecutive values are exactly those of
    input buffer ``in_val`` (every value linked, in order, from one source buffer), or
    None. A set then passes that pointer instead of copying the values first: the same
    doubles reach the FMU."""
    links = sorted(links, key=lambda link: link[0])
    if not links or len(links) != len(in_val):
        return None
    src, first = links[0][1], links[0][2]
    if any(s is not src or j != k or pos != first + k for k, (j, s, pos) in enumerate(links)):
        return None
    ctype = in_val._type_
    if src._type_ is not ctype or first + len(in_val) > len(src):
        return None
    pointer = ctypes.cast(ctypes.byref(src, first * ctypes.sizeof(ctype)),
                          ctypes.POINTER(ctype))
    pointer.keep = src  # the source buffer lives as long
    return pointer


class Code:
    """Source text of a generated function and the objects it uses (its closure)."""

    INDENT = "        "

    def __init__(self, **fixed: Any) -> None:
        self.lines: list[str] = []
        self.bound: dict[str, Any] = dict(fixed)

    def bind(self, value: Any, prefix: str = "v") -> str:
        """A fresh identifier for ``value``."""
        name = f"{prefix}{len(self.bound)}"
        self.bound[name] = value
        return name

    def line(self, text: str) -> None:
        self.lines.append(self.INDENT + text)

    def call(self, fn: Any, args: tuple[Any, ...], what: str) -> None:
        """``s = fn(arg, ...)`` with each argument bound once, then the status check
        (above Warning: the exception fmpy's wrapper raises, naming ``what``)."""
        fn, args = bare_call(fn, args)
        names = [self.bind(a, "a") for a in args]
        self.line(f"s = {self.bind(fn, 'f')}({', '.join(names)})")
        self.line(f"if s > 1: raise failed({self.bind(what, 'n')}, s)")

    def finite_check(self, unit: Unit, group: Group) -> None:
        """The finite check of a float buffer: a sum of its values first (a sum is finite
        only if every term is; an overflowed sum lands in the full check, which then
        finds nothing)."""
        _, _, buf, is_float, _, _ = group
        if is_float and len(buf):
            b = self.bind(buf, "b")
            total = " + ".join(f"{b}[{i}]" for i in range(len(buf)))
            self.line(f"if not isfinite({total}): check({self.bind(unit, 'u')}, t)")

    def get(self, unit: Unit, group: Group, check: bool) -> None:
        """One batched get of output ``group`` of ``unit``, and with ``check`` its
        finite check."""
        fn, args, _, _, fname, _ = group
        self.call(fn, args, fname)
        if check:
            self.finite_check(unit, group)

    def function(self, name: str, params: str) -> Callable[..., Any]:
        """The function ``name(params)`` whose body is the lines added so far; its source
        is in :mod:`linecache` as long as the function lives."""
        closure = ", ".join(self.bound)
        body = "\n".join(self.lines) or self.INDENT + "pass"
        source = (f"def _make({closure}):\n    def {name}({params}):\n{body}\n"
                  f"    return {name}\n")
        filename = f"<agv_cosim fast path: {name} #{next(_NUMBERS)}>"
        namespace: dict[str, Any] = {}
        exec(compile(source, filename, "exec"), namespace)  # noqa: S102
        function: Callable[..., Any] = namespace["_make"](**self.bound)
        linecache.cache[filename] = (len(source), None, source.splitlines(True), filename)
        weakref.finalize(function, linecache.cache.pop, filename, None)
        return function


def gauss_seidel_pass(pre_read: list[Unit], ordered: list[Unit], read_once: set[str],
                      track: Any, stopped: Iterable[str] = ()) -> Callable[[float], None]:
    """The Gauss-Seidel pass (:meth:`agv_cosim.execution.algorithm.GaussSeidel.pass_at`)
    as one generated function ``gs_pass(t)``; units named in ``stopped`` get no sets."""
    stopped = set(stopped)
    code = Code(track=track, failed=failed, isfinite=isfinite, check=check_finite)
    for unit in pre_read:
        code.line(f"track[0] = {int(unit.index)}")
        for group in unit.out_groups:
            code.get(unit, group, unit.name in read_once)
    for unit in ordered:
        in_groups = () if unit.name in stopped else unit.in_groups
        out_groups = () if unit.name in read_once else unit.out_groups
        if not (in_groups or out_groups):
            continue
        code.line(f"track[0] = {int(unit.index)}")
        for fn, args, in_val, links, fname in in_groups:
            shared = shared_values(in_val, links)
            if shared is not None:  # the source's buffer is the values argument
                code.call(fn, args[:3] + (shared,) + args[4:], fname)
                continue
            target = code.bind(in_val, "b")
            for j, src, pos in links:
                code.line(f"{target}[{int(j)}] = {code.bind(src, 'b')}[{int(pos)}]")
            code.call(fn, args, fname)
        for group in out_groups:
            code.get(unit, group, True)
    return code.function("gs_pass", "t")


def jacobi_get(units: list[Unit], track: Any) -> Callable[[float], None]:
    """Every unit's outputs read, then checked (:meth:`Jacobi.read_all`), generated."""
    code = Code(track=track, failed=failed, isfinite=isfinite, check=check_finite)
    for unit in units:
        code.line(f"track[0] = {int(unit.index)}")
        for fn, args, _, _, fname, _ in unit.out_groups:
            code.call(fn, args, fname)
        if not unit.table:  # a table's values are checked when it is read
            for group in unit.out_groups:
                code.finite_check(unit, group)
    return code.function("jacobi_get", "t")


def jacobi_set(units: list[Unit], track: Any) -> Callable[[], None]:
    """Every unit's inputs copied from their sources and set (:meth:`Jacobi.set_all`),
    generated."""
    code = Code(track=track, failed=failed)
    for unit in units:
        code.line(f"track[0] = {int(unit.index)}")
        for fn, args, in_val, links, fname in unit.in_groups:
            target = code.bind(in_val, "b")
            for j, src, pos in links:
                code.line(f"{target}[{int(j)}] = {code.bind(src, 'b')}[{int(pos)}]")
            code.call(fn, args, fname)
    return code.function("jacobi_set", "")


def step_all(units: list[FmuUnit], track: Any, phase: int,
             fmi2_stepped: Callable[..., None],
             fmi3_stepped: Callable[..., None],
             requests: list[tuple[str, float | None]]) -> Callable[[float, float], None]:
    """``step_all(t, h)``: every unit steps from ``t`` to ``t + h`` [s] in turn
    (:meth:`agv_cosim.execution.algorithm.Stepper.step_reference`), generated."""
    # FMI 2.0: the time and step size pass as two C doubles shared by every doStep of the
    # macro step (their values stored once a step), the component and the flag converted
    # once (bare_call): no per-call argument conversion
    t_c, h_c = ctypes.c_double(0.0), ctypes.c_double(0.0)
    code = Code(track=track, stops=requests, t_c=t_c, h_c=h_c)
    code.line("track[2] = t")
    code.line(f"track[1] = {int(phase)}")
    code.line("t_c.value = t")
    code.line("h_c.value = h")
    for unit in units:
        d, c, u = code.bind(unit.do_step, "f"), code.bind(unit.component, "a"), \
            code.bind(unit, "u")
        code.line(f"track[0] = {int(unit.index)}")
        if unit.step_extra is None:
            bare, args = bare_call(unit.do_step, (unit.component, t_c, h_c, 1))
            if bare is not unit.do_step:
                names = [code.bind(a, "a") for a in args]
                code.line(f"s = {code.bind(bare, 'f')}({', '.join(names)})")
            else:
                code.line(f"s = {d}({c}, t, h, 1)")
            code.line(f"if s > 1: {code.bind(fmi2_stepped, 'g')}({u}, s, stops)")
        else:
            extra = ", ".join(code.bind(e, "a") for e in unit.step_extra)
            code.line(f"s = {d}({c}, t, h, True, {extra})")
            code.line(f"if s > 1 or {code.bind(unit.flags[1], 'a')}.value: "
                      f"{code.bind(fmi3_stepped, 'g')}({u}, s, stops)")
    return code.function("step_all", "t, h")
