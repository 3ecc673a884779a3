"""The per-step functions of :mod:`.fastpath` as compiled programs (:mod:`.compiled`).

Each function here returns a ``Program`` of the extension that makes exactly the calls of
the generated function of the same name in :mod:`.fastpath` (same functions, arguments,
order, status checks, finite checks and track writes), or None when the run has
something the compiled path does not handle, and the caller then generates the Python
function as before:

- the extension is not available (:func:`.compiled.module`: not built, or switched off);
- a call goes through fmpy's wrapper (an fmpy call logger is set) or a C function
  without the declared argument types of an FMI 2.0 / 3.0 get, set or doStep;
- an input is copied between buffers of different C types, or of a type that is not a
  plain number (strings: ctypes keeps the copied bytes alive, a copy in C would not);
- a checked output buffer is not of C doubles.

A table's values are filled by its Python function, called from the program.
"""

import ctypes
from collections.abc import Callable, Iterable
from typing import Any

from . import compiled
from .units import FmuUnit, Group, Unit, check_finite, failed

__all__ = ["gauss_seidel_pass", "jacobi_get", "jacobi_set", "step_all", "track_address"]

OP_TRACK, OP_TIME, OP_COPY, OP_CALL2, OP_CALL3, OP_PY, OP_STEP2, OP_STEP3, OP_CHECK = range(9)
_FUNCTION_BASE: Any = ctypes._CFuncPtr  # type: ignore[attr-defined]
_SIMPLE: Any = ctypes._SimpleCData


class _Refused(Exception):
    """The run has something the compiled path does not handle."""


def _address(value: Any) -> int:
    """The address a ctypes object (array, pointer, c_void_p) or int stands for."""
    if value is None:
        return 0
    if isinstance(value, int):
        return value
    if isinstance(value, ctypes.Array):
        return ctypes.addressof(value)
    if isinstance(value, (ctypes._Pointer, ctypes.c_void_p)):
        return ctypes.cast(value, ctypes.c_void_p).value or 0
    raise _Refused(f"not an address: {type(value).__name__}")


def _function(fn: Any, count: int) -> int:
    """The address of C function ``fn`` declared with ``count`` argument types."""
    if not isinstance(fn, _FUNCTION_BASE) or len(getattr(fn, "argtypes", None) or ()) \
            != count:
        raise _Refused("not a declared C function")
    address = ctypes.cast(fn, ctypes.c_void_p).value
    if not address:
        raise _Refused("a null function")
    return address


def _plain_number(ctype: Any) -> bool:
    """True for a ctypes scalar that holds a number (not a string or pointer)."""
    code: Any = getattr(ctype, "_type_", None)
    return isinstance(ctype, type) and issubclass(ctype, _SIMPLE) and \
        isinstance(code, str) and code not in "zZPOXv"


def track_address(track: Any) -> int | None:
    """The address of the track's three doubles when it is a ctypes array of them (a
    shared ``RawArray``), else None (the program writes it item by item)."""
    if isinstance(track, ctypes.Array) and track._type_ is ctypes.c_double and \
            len(track) >= 3:
        return ctypes.addressof(track)
    return None


class _Ops:
    """The operations of one program and the objects they point into."""

    def __init__(self, track: Any) -> None:
        self.track = track
        self.ops: list[tuple[Any, ...]] = []
        self.keep: list[Any] = []

    def _op(self, kind: int, slot: int = 0, value: float = 0.0, fn: int = 0, comp: int = 0,
            vrs: int = 0, n: int = 0, buf: int = 0, nvalues: int = 0, check: int = 0,
            ncheck: int = 0, size: int = 0, src: int = 0,
            flags: tuple[int, int, int, int] | None = None, name: str = "",
            unit: Any = None, py: Any = None) -> None:
        self.ops.append((kind, slot, float(value), fn or None, comp or None, vrs or None, n,
                         buf or None, nvalues, check or None, ncheck, size, src or None,
                         flags, name, unit, py))

    def track_to(self, slot: int, value: int) -> None:
        self._op(OP_TRACK, slot=slot, value=value)

    def time(self) -> None:
        self._op(OP_TIME, slot=2)

    def call(self, fn: Any, args: tuple[Any, ...], name: str, unit: Unit | None = None,
             checked: Any = None) -> None:
        """One get / set call (``fn(*args)``), its status checked; with ``checked`` (a
        buffer of C doubles) the finite check of that buffer after it."""
        check = 0
        if checked is not None:
            if checked._type_ is not ctypes.c_double:
                raise _Refused("a checked buffer that is not of doubles")
            check = ctypes.addressof(checked)
        self.keep.extend(args)
        if not isinstance(fn, _FUNCTION_BASE):
            if args:
                raise _Refused("a Python function with arguments")
            self._op(OP_PY, name=name, unit=unit, py=fn, check=check,
                     ncheck=len(checked) if checked is not None else 0)
            return
        if len(args) not in (4, 5):
            raise _Refused("not an FMI get / set")
        self.keep.append(fn)
        n = int(args[2])
        nvalues = int(args[4]) if len(args) == 5 else 0
        self._op(OP_CALL3 if len(args) == 5 else OP_CALL2, fn=_function(fn, len(args)),
                 comp=_address(args[0]), vrs=_address(args[1]), n=n, buf=_address(args[3]),
                 nvalues=nvalues, check=check,
                 ncheck=len(checked) if checked is not None else 0, name=name, unit=unit)

    def check(self, unit: Unit, buf: Any) -> None:
        """The finite check of ``buf`` (C doubles) of ``unit``."""
        if buf._type_ is not ctypes.c_double:
            raise _Refused("a checked buffer that is not of doubles")
        self.keep.append(buf)
        self._op(OP_CHECK, check=ctypes.addressof(buf), ncheck=len(buf), unit=unit)

    def copy(self, target: Any, j: int, src: Any, pos: int) -> None:
        """``target[j] = src[pos]`` as a copy of the value's bytes."""
        ctype = target._type_
        if src._type_ is not ctype or not _plain_number(ctype) or \
                not (0 <= j < len(target) and 0 <= pos < len(src)):
            raise _Refused("a copy between buffers of other types")
        size = ctypes.sizeof(ctype)
        self.keep.extend((target, src))
        self._op(OP_COPY, buf=ctypes.addressof(target) + j * size,
                 src=ctypes.addressof(src) + pos * size, size=size)

    def program(self, requests: list[Any] | None = None) -> Any:
        module = compiled.module()
        assert module is not None  # checked by _build
        return module.Program(tuple(self.ops), track_address(self.track), self.track,
                              failed, check_finite, [] if requests is None else requests,
                              tuple(self.keep))


def _build(make: Callable[[_Ops], None], track: Any,
           requests: list[Any] | None = None) -> Any:
    if compiled.module() is None:
        return None
    ops = _Ops(track)
    try:
        make(ops)
    except _Refused:
        return None
    return ops.program(requests)


def _get(ops: _Ops, unit: Unit, group: Group, check: bool) -> None:
    fn, args, buf, is_float, fname, _ = group
    ops.call(fn, args, fname, unit, buf if check and is_float and len(buf) else None)


def gauss_seidel_pass(pre_read: list[Unit], ordered: list[Unit], read_once: set[str],
                      track: Any, stopped: Iterable[str] = ()) -> Any:
    """:func:`.fastpath.gauss_seidel_pass` as a program ``gs_pass(t)``, or None."""
    stopped = set(stopped)

    def make(ops: _Ops) -> None:
        for unit in pre_read:
            ops.track_to(0, int(unit.index))
            for group in unit.out_groups:
                _get(ops, unit, group, unit.name in read_once)
        for unit in ordered:
            in_groups = () if unit.name in stopped else unit.in_groups
            out_groups = () if unit.name in read_once else unit.out_groups
            if not (in_groups or out_groups):
                continue
            ops.track_to(0, int(unit.index))
            for fn, args, in_val, links, fname in in_groups:
                for j, src, pos in links:
                    ops.copy(in_val, int(j), src, int(pos))
                ops.call(fn, args, fname)
            for group in out_groups:
                _get(ops, unit, group, True)

    return _build(make, track)


def jacobi_get(units: list[Unit], track: Any) -> Any:
    """:func:`.fastpath.jacobi_get` as a program ``jacobi_get(t)``, or None."""

    def make(ops: _Ops) -> None:
        for unit in units:
            ops.track_to(0, int(unit.index))
            for fn, args, _, _, fname, _ in unit.out_groups:
                ops.call(fn, args, fname, unit)
            if not unit.table:  # the finite checks after all the unit's gets
                for group in unit.out_groups:
                    _, _, buf, is_float, _, _ = group
                    if is_float and len(buf):
                        ops.check(unit, buf)

    return _build(make, track)


def jacobi_set(units: list[Unit], track: Any) -> Any:
    """:func:`.fastpath.jacobi_set` as a program ``jacobi_set()``, or None."""

    def make(ops: _Ops) -> None:
        for unit in units:
            ops.track_to(0, int(unit.index))
            for fn, args, in_val, links, fname in unit.in_groups:
                for j, src, pos in links:
                    ops.copy(in_val, int(j), src, int(pos))
                ops.call(fn, args, fname)

    return _build(make, track)


def step_all(units: list[FmuUnit], track: Any, phase: int,
             fmi2_stepped: Callable[..., None], fmi3_stepped: Callable[..., None],
             requests: list[tuple[str, float | None]]) -> Any:
    """:func:`.fastpath.step_all` as a program ``step_all(t, h)``, or None."""

    def make(ops: _Ops) -> None:
        ops.time()
        ops.track_to(1, int(phase))
        for unit in units:
            ops.track_to(0, int(unit.index))
            ops.keep.append(unit.do_step)
            comp = _address(unit.component)
            if unit.step_extra is None:
                ops._op(OP_STEP2, fn=_function(unit.do_step, 4), comp=comp,
                        name="fmi2DoStep", unit=unit, py=fmi2_stepped)
            else:
                ops.keep.append(unit.flags)
                flags = tuple(ctypes.addressof(f) for f in unit.flags)
                ops._op(OP_STEP3, fn=_function(unit.do_step, 8), comp=comp,
                        flags=(flags[0], flags[1], flags[2], flags[3]),
                        name="fmi3DoStep", unit=unit, py=fmi3_stepped)

    return _build(make, track, requests)
