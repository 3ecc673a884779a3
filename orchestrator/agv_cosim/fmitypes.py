"""Everything the orchestrator knows about FMI variable types, in one place.

One :class:`FmiType` per type name of each FMI version says how a value of that type is
checked when a manifest gives it (:func:`parse`), read from model-description or SSP text
(:func:`parse_text`), written as text (:func:`format_text`), recorded in
``timeseries.csv`` (:func:`record_format`), held in C (``ctype``) and moved through the
FMI API (``get``/``set``: the batched C functions; ``py_set``: fmpy's convenience
setter, used for parameters before initialisation).

Types (``kind`` is the value class a connection must keep):

========================  ==============  =============  ================================
FMI 2.0                   FMI 3.0         kind           recorded as
========================  ==============  =============  ================================
Real                      Float64         float64        ``repr`` of the double
(none)                    Float32         float32        ``repr`` of the value as a double
Integer                   Int32           int32          decimal integer
(none)                    Int8 .. UInt64  int8 .. uint64 decimal integer
Enumeration               Enumeration     enumeration    decimal integer (the item value)
Boolean                   Boolean         boolean        ``1`` / ``0``
String                    String          string         CSV-quoted text (quotes doubled)
========================  ==============  =============  ================================

A connection needs the same ``kind`` on both ends (Real -> Float64 between an FMI 2.0
and an FMI 3.0 FMU is fine; Integer -> Real is not: there is no implicit conversion).
FMI 3.0 Binary and Clock variables are read but refused wherever they would be used.
"""

import ctypes
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class FmiType:
    """One variable type of one FMI version."""

    name: str        # as written in modelDescription.xml
    version: str     # "2.0" or "3.0"
    kind: str        # value class a connection must keep (see the module table)
    ctype: Any       # ctypes scalar type of a value (c_double, c_int32, ...)
    get: str         # batched C getter, e.g. "fmi2GetReal"
    set: str         # batched C setter
    py_set: str      # fmpy convenience setter (e.g. "setReal")
    bounds: tuple[int, int] | None = None  # (lowest, highest) for integer kinds

    @property
    def is_float(self) -> bool:
        return self.kind in ("float64", "float32")

    @property
    def is_integer(self) -> bool:
        return self.bounds is not None

    @property
    def numeric(self) -> bool:
        """Recorded by default (a number a metric or plot can use)."""
        return self.kind != "string"

    @property
    def ssp_type(self) -> str:
        """The SSP connector/parameter type element (``ssc:``/``ssv:`` local name)."""
        if self.is_float:
            return "Real"
        return {"boolean": "Boolean", "string": "String",
                "enumeration": "Enumeration"}.get(self.kind, "Integer")


def _int_bounds(bits: int, signed: bool) -> tuple[int, int]:
    return (-2 ** (bits - 1), 2 ** (bits - 1) - 1) if signed else (0, 2 ** bits - 1)


def _table() -> dict[tuple[str, str], FmiType]:
    c = ctypes
    types = [
        FmiType("Real", "2.0", "float64", c.c_double, "fmi2GetReal", "fmi2SetReal",
                "setReal"),
        FmiType("Integer", "2.0", "int32", c.c_int, "fmi2GetInteger", "fmi2SetInteger",
                "setInteger", _int_bounds(32, True)),
        FmiType("Enumeration", "2.0", "enumeration", c.c_int, "fmi2GetInteger",
                "fmi2SetInteger", "setInteger", _int_bounds(32, True)),
        FmiType("Boolean", "2.0", "boolean", c.c_int, "fmi2GetBoolean", "fmi2SetBoolean",
                "setBoolean"),
        FmiType("String", "2.0", "string", c.c_char_p, "fmi2GetString", "fmi2SetString",
                "setString"),
        FmiType("Float64", "3.0", "float64", c.c_double, "fmi3GetFloat64",
                "fmi3SetFloat64", "setFloat64"),
        FmiType("Float32", "3.0", "float32", c.c_float, "fmi3GetFloat32",
                "fmi3SetFloat32", "setFloat32"),
        FmiType("Enumeration", "3.0", "enumeration", c.c_int64, "fmi3GetInt64",
                "fmi3SetInt64", "setInt64", _int_bounds(64, True)),
        FmiType("Boolean", "3.0", "boolean", c.c_bool, "fmi3GetBoolean", "fmi3SetBoolean",
                "setBoolean"),
        FmiType("String", "3.0", "string", c.c_char_p, "fmi3GetString", "fmi3SetString",
                "setString"),
    ]
    for bits in (8, 16, 32, 64):
        for signed in (True, False):
            name = f"{'' if signed else 'U'}Int{bits}"
            ctype = getattr(c, f"c_{'' if signed else 'u'}int{bits}")
            types.append(FmiType(name, "3.0", name.lower(), ctype, f"fmi3Get{name}",
                                 f"fmi3Set{name}", f"set{name}", _int_bounds(bits, signed)))
    return {(t.version, t.name): t for t in types}


TYPES = _table()
#: Type element names a model description may use, per FMI version (including the ones
#: read but not supported).
NAMES = {"2.0": ("Real", "Integer", "Boolean", "String", "Enumeration"),
         "3.0": tuple(n for v, n in TYPES if v == "3.0") + ("Binary", "Clock")}


#: Value types of SSP parameters and connectors (SSP uses FMI 2.0's names; Enumeration
#: and Binary values are not supported).
SSP_VALUE_TYPES = NAMES["2.0"][:4]


def lookup(version: str, name: str) -> FmiType | None:
    """The :class:`FmiType` of type ``name`` in FMI ``version``, or None if unsupported."""
    return TYPES.get((version, name))


def of(variable: Any) -> FmiType | None:
    """The :class:`FmiType` of a model variable (``variable.fmi`` / ``variable.type``)."""
    return TYPES.get((variable.fmi, variable.type))


def compatible(a: FmiType | None, b: FmiType | None) -> bool:
    """True when an output of type ``a`` may feed an input of type ``b``."""
    return a is not None and b is not None and a.kind == b.kind


def _number(text: str | None) -> float | None:
    if text is None:
        return None
    try:
        return float(text)
    except (TypeError, ValueError):
        return None


def declares_legal(variable: Any, value: Any) -> bool:
    """True when ``variable`` declares the non-finite ``value`` legal.

    What we take as a declaration (FMI has no explicit one): +inf when its ``max`` (or
    its declared type's) is ``INF``; -inf when its ``min`` is ``-INF``; NaN when its
    ``start`` value is ``NaN`` (the FMU itself then uses NaN as a value). Anything else
    non-finite is refused.
    """
    if variable is None:
        return False
    if math.isnan(value):
        start = _number((variable.start or "").split()[0] if variable.start else None)
        return start is not None and math.isnan(start)
    bound = _number(variable.max if value > 0 else variable.min)
    return bound is not None and bound == value


def parse(ftype: FmiType, value: Any, variable: Any = None) -> Any:
    """A manifest (TOML) value checked for ``ftype``; ValueError with a one-line reason.

    Strict: a float type takes an int or float (not a bool), finite unless ``variable``
    (the model variable it is for) declares the value legal (:func:`declares_legal`:
    ``nan``, ``inf`` and an overflowing literal such as ``1e999`` are refused
    otherwise); an integer or enumeration type a whole int in its range (not a float,
    not a bool), Boolean a bool, String a str.
    """
    if ftype.is_float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ValueError(f"is {ftype.name}, got {value!r}")
        try:
            value = float(value)
        except OverflowError:  # an int beyond every double
            raise ValueError(f"= {value!r} is out of the range of a {ftype.name}") from None
        if not math.isfinite(value) and not declares_legal(variable, value):
            raise ValueError(f"= {value!r} is not a finite number (the FMU does not declare "
                             "it legal: a NaN start value, or max = INF / min = -INF)")
        if ftype.kind == "float32" and math.isfinite(value) and abs(value) > 3.4028234663852886e38:
            raise ValueError(f"= {value!r} is out of the range of a {ftype.name}")
        return value
    if ftype.is_integer:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ValueError(f"is {ftype.name}, got {value!r}")
        low, high = ftype.bounds or (value, value)
        if not low <= value <= high:
            raise ValueError(f"= {value!r} is out of the range of an FMI {ftype.name} "
                             f"({low} .. {high})")
        return value
    if ftype.kind == "boolean":
        if not isinstance(value, bool):
            raise ValueError(f"is {ftype.name}, got {value!r}")
        return value
    if not isinstance(value, str):
        raise ValueError(f"is {ftype.name}, got {value!r}")
    return value


def parse_array(ftype: FmiType, value: Any, size: int, variable: Any = None) -> tuple[Any, ...]:
    """A manifest value for a whole FMI 3.0 array of ``size`` elements: a flat list in
    row-major order, each element checked by :func:`parse`; returned as a tuple."""
    if not isinstance(value, list):
        raise ValueError(f"is an array of {size} {ftype.name} (a flat list in row-major "
                         f"order), got {value!r}")
    if len(value) != size:
        raise ValueError(f"has {size} elements, got a list of {len(value)}")
    items = []
    for i, item in enumerate(value):
        try:
            items.append(parse(ftype, item, variable))
        except ValueError as error:
            problem = str(error)
            if problem.startswith("is "):  # a type mismatch stays one (see manifest)
                raise ValueError(f"is an array of {ftype.name}: element {i + 1} "
                                 f"{problem}") from None
            raise ValueError(f"element {i + 1} {problem}") from None
    return tuple(items)


def parse_text(ftype: FmiType, text: str) -> Any:
    """A value from model-description or SSP text (``start``, ``ssv`` values)."""
    if ftype.is_float:
        return float(text)
    if ftype.is_integer:
        return int(text)
    if ftype.kind == "boolean":
        if text not in ("true", "false", "1", "0"):
            raise ValueError(f"{text!r} is not a Boolean")
        return text in ("true", "1")
    return text


def format_text(ftype: FmiType, value: Any) -> str:
    """``value`` as model-description / SSP text (inverse of :func:`parse_text`)."""
    if ftype.is_float:
        return repr(float(value))
    if ftype.kind == "boolean":
        return "true" if value else "false"
    if ftype.is_integer:
        return str(int(value))
    return str(value)


def _csv_quote(text: str) -> str:
    return '"' + text.replace('"', '""') + '"'


def _record_string(value: bytes | str | None) -> str:
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    return _csv_quote("" if value is None else value)


def record_format(ftype: FmiType) -> Callable[[Any], str]:
    """Callable turning a value read from the FMU into its ``timeseries.csv`` text."""
    if ftype.is_float:
        return lambda value: repr(float(value))
    if ftype.kind == "boolean":
        return lambda value: "1" if value else "0"
    if ftype.is_integer:
        return lambda value: str(int(value))
    return _record_string


def to_c(ftype: FmiType, value: Any) -> Any:
    """A Python value as the C buffer element for ``ftype`` (strings as UTF-8 bytes)."""
    if ftype.kind == "string":
        return value.encode("utf-8")
    return value


def set_parameter(slave: Any, ftype: FmiType, vr: int, value: Any) -> None:
    """Set one variable through fmpy's convenience setter (before initialisation).

    A tuple ``value`` sets a whole FMI 3.0 array (one call, row-major values)."""
    if isinstance(value, tuple):
        getattr(slave, ftype.py_set)([vr], [_py_value(ftype, v) for v in value])
        return
    getattr(slave, ftype.py_set)([vr], [_py_value(ftype, value)])


def _py_value(ftype: FmiType, value: Any) -> float | int | bool | str:
    if ftype.is_float:
        return float(value)
    if ftype.is_integer:
        return int(value)
    if ftype.kind == "boolean":
        return bool(value)
    return str(value)
