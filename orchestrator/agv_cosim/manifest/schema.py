"""The manifest's schema, declared once (pydantic v2 models), and its one-line errors.

Every table of a manifest is a model here: the top level, ``[simulation]``,
``[components.X]``, ``[[connections]]``, ``[events.X]``, ``[variants.X]``, ``[sweep]``,
``[record]``, ``[metrics]`` and ``[plots]``. Unknown keys are refused (``extra="forbid"``)
and scalars are strict: a number is an int or a float (never a bool or a string, and
finite), a string is a string. What is not shape (names that refer to declared components,
step multiples, FMU binding, cycles) is checked in plain code by the stage that owns it
(:mod:`agv_cosim.manifest`, :mod:`agv_cosim.plan`, :mod:`agv_cosim.system`).

:func:`check` validates data against a model; a problem is a :class:`SchemaError` whose
``key`` is the dotted key (``components.vehicle.fmu``, ``connections[2].from``,
``metrics.reference.path``) and whose ``problem`` is a short text.
"""

import types
import typing
from typing import Annotated, Any, Literal, TypeGuard, TypeVar

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Field,
    StrictInt,
    StrictStr,
    ValidationError,
    ValidationInfo,
    field_validator,
    model_validator,
)
from pydantic_core import ErrorDetails

from ..errors import SchemaError, closest, did_you_mean

M = TypeVar("M", bound=BaseModel)

#: Default settling band of the lateral error [m] (``[metrics] settle_band``).
DEFAULT_SETTLE_BAND = 0.02
#: Default resolution of the figures [dots per inch] (``[plots] dpi``).
DEFAULT_DPI = 120


def _dotted(what: str) -> AfterValidator:
    def check(text: str) -> str:
        # split at the first dot: a component name has none, a variable name may have
        # any number (Modelica's "body.frame_a.r_0[1]")
        left, dot, right = text.partition(".")
        if not dot or not left or not right:
            raise ValueError(f"{text!r} is not of the form '{what}'")
        return text
    return AfterValidator(check)


#: A finite number; an int is taken as a float, a bool or a string is refused.
Number = Annotated[float, Field(strict=True, allow_inf_nan=False)]
#: ``"component.variable"``
Dotted = Annotated[StrictStr, _dotted("component.variable")]


def _signal(text: str) -> str:
    component, dot, variable = text.partition(".")
    if not dot or not component or not variable:
        raise ValueError(f"signal name {text!r} is not 'component.variable'")
    return text


#: A recorded signal ``"component.variable"`` (the variable's name may hold dots).
Signal = Annotated[StrictStr, AfterValidator(_signal)]


class _Table(BaseModel):
    model_config = ConfigDict(extra="forbid", populate_by_name=True)


# --------------------------------------------------------------------------- manifest

class Simulation(_Table):
    start: Number = 0.0
    stop: Number
    step: Annotated[Number, Field(gt=0)]
    algorithm: Literal["gauss-seidel", "jacobi"] = "gauss-seidel"
    #: wall-clock limit of each run [s]; a run still going then is stopped, ``timed out``
    timeout: Annotated[Number, Field(gt=0)] | None = None


class ComponentTable(_Table):
    """An FMU (``fmu``, ``parameters``) or a time table (``table``, ``interpolation``,
    ``units``); which one is checked in :mod:`agv_cosim.manifest`."""

    fmu: StrictStr | None = None
    parameters: dict[str, Any] = {}
    table: StrictStr | None = None
    interpolation: dict[str, Any] = {}
    units: dict[str, Any] = {}
    #: the component's own communication step [s], a whole multiple of ``[simulation]
    #: step`` (checked in :mod:`agv_cosim.manifest`); None: the simulation's step
    step: Annotated[Number, Field(gt=0)] | None = None
    #: the FMI interface it runs through, and an integrated one's solver and relative
    #: tolerance (:mod:`agv_cosim.system.interface`; checked with the FMU there)
    interface: Literal["co-simulation", "model-exchange"] | None = None
    solver: Literal["cvode", "scipy"] | None = None
    tolerance: Annotated[Number, Field(gt=0, lt=1)] | None = None


class ConnectionTable(_Table):
    source: Dotted = Field(alias="from")
    target: Dotted = Field(alias="to")


class EventTable(_Table):
    """``at`` [s] and ``set`` ("component.variable" -> value). A variant may give either
    of them for an event of the base (its presence is checked in the manifest stage)."""

    at: Number | None = None
    set: Annotated[dict[Annotated[str, _dotted("component.variable")], Any],
                   Field(min_length=1)] | None = None


class VariantTable(_Table):
    """Changes to the base experiment: ``components`` changed or added (a name the base
    has not, or one the variant removes), base components removed (``remove``), base
    connections removed (``disconnect``: ``"component.input"`` the one driving that
    input, ``"component"`` every one to or from it), ``connections`` added, ``events``
    changed or added. Names are checked in :mod:`agv_cosim.manifest`, the resulting
    system like a base one in :mod:`agv_cosim.system`."""

    description: StrictStr = ""
    components: dict[str, ComponentTable] = {}
    remove: list[StrictStr] = []
    disconnect: list[StrictStr] = []
    connections: list[ConnectionTable] = []
    events: dict[str, EventTable] = {}


class RecordTable(_Table):
    variables: Annotated[list[Dotted], Field(min_length=1)] | None = None
    interval: Number | None = None


class Saturation(_Table):
    signal: Signal
    limit: Annotated[Number, Field(gt=0)]
    tolerance: Annotated[Number, Field(ge=0)] | None = None

    @field_validator("tolerance")
    @classmethod
    def _below_limit(cls, tolerance: float | None, info: ValidationInfo) -> float | None:
        limit = info.data.get("limit")
        if limit is not None and tolerance is not None and tolerance >= limit:
            raise ValueError(f"must be < limit ({limit!r}), got {tolerance!r}")
        return tolerance

    @model_validator(mode="after")
    def _default_tolerance(self) -> "Saturation":
        if self.tolerance is None:
            self.tolerance = 1e-9 * self.limit
        return self


def _path_text(text: str) -> str:
    if not text.strip():
        raise ValueError(f"expected a path string, got {text!r}")
    return text


PathText = Annotated[StrictStr, AfterValidator(_path_text)]


class Reference(_Table):
    path: PathText
    x: Signal
    y: Signal


class MetricsTable(_Table):
    """``[metrics]`` (documented in :mod:`agv_cosim.report.metrics` and docs/metrics.md)."""

    lateral_error: Signal | None = None
    heading_error: Signal | None = None
    steering_angle: Signal | None = None
    steering_rate: Signal | None = None
    control: Signal | None = None
    settle_band: Annotated[Number, Field(gt=0)] = DEFAULT_SETTLE_BAND
    settle_after: Annotated[Number, Field(ge=0)] | None = None
    saturation: Saturation | None = None
    reference: Reference | None = None

    def spec(self) -> dict[str, Any]:
        """The table as the dict :mod:`agv_cosim.report.metrics` computes from (defaults
        in)."""
        return self.model_dump(exclude_none=True)


def _x_axis(text: str) -> str:
    if text != "time":
        _signal(text)
    return text


class Trajectory(_Table):
    x: Signal
    y: Signal
    path: PathText | None = None


class PlotsTable(_Table):
    """``[plots]`` (documented in :mod:`agv_cosim.plots`)."""

    signals: Annotated[list[Signal], Field(min_length=1)] | None = None
    x: Annotated[StrictStr, AfterValidator(_x_axis)] = "time"
    units: dict[str, StrictStr] = {}
    title: StrictStr | None = None
    dpi: Annotated[StrictInt, Field(ge=10, le=1200)] = DEFAULT_DPI
    trajectory: Trajectory | None = None

    def spec(self) -> dict[str, Any]:
        """The table as the dict :mod:`agv_cosim.report.plots` draws from (defaults in)."""
        out = self.model_dump(exclude={"signals", "trajectory"})
        if self.signals is not None:
            out["signals"] = list(self.signals)
        if self.trajectory is not None:
            out["trajectory"] = self.trajectory.model_dump()
        return out


class Normal(_Table):
    distribution: Literal["normal"]
    mean: Number
    std: Annotated[Number, Field(gt=0)]


class _Bounded(_Table):
    low: Number
    high: Number

    @field_validator("high")
    @classmethod
    def _above_low(cls, high: float, info: ValidationInfo) -> float:
        low = info.data.get("low")
        if low is not None and not low < high:
            raise ValueError(f"{high!r} must be > low ({low!r})")
        return high


class Uniform(_Bounded):
    distribution: Literal["uniform"]


class TruncNormal(_Bounded):
    distribution: Literal["truncnormal"]
    mean: Number
    std: Annotated[Number, Field(gt=0)]


class Choice(_Table):
    distribution: Literal["choice"]
    values: Annotated[list[Any], Field(min_length=1)]
    weights: list[Number] | None = None

    @field_validator("weights")
    @classmethod
    def _one_weight_a_value(cls, weights: list[float] | None,
                            info: ValidationInfo) -> list[float] | None:
        if weights is not None:
            if len(weights) != len(info.data.get("values") or ()):
                raise ValueError("must be an array of one number per value")
            if min(weights) < 0 or sum(weights) <= 0:
                raise ValueError("must be >= 0 with a positive sum")
        return weights


#: A sampled parameter's distribution, told by its ``distribution`` key.
Distribution = Annotated[Normal | Uniform | TruncNormal | Choice,
                         Field(discriminator="distribution")]


class MonteCarloTable(_Table):
    """``[montecarlo]`` (documented in :mod:`agv_cosim.montecarlo`); names are checked
    against the components and the sweep by :func:`agv_cosim.montecarlo.parse`."""

    samples: Annotated[StrictInt, Field(ge=1, le=100_000)]  # plan.MAX_RUNS
    seed: Annotated[StrictInt, Field(ge=0)]
    design: Literal["random", "sobol", "lhs"] = "random"
    parameters: dict[str, Distribution] = {}
    seeds: list[Annotated[StrictStr, _dotted("component.parameter")]] = []
    metrics: Annotated[list[StrictStr], Field(min_length=1)] | None = None
    band: Dotted | None = None


class Bounds(_Table):
    """The bounds of a fitted or tuned parameter (``[fit.parameters."<c.p>"]``,
    ``[tune.parameters."<c.p>"]``); its start is the manifest's value (checked against
    the runs by :mod:`agv_cosim.manifest_fit.checks` and :mod:`agv_cosim.tuning`)."""

    min: Number
    max: Number


class TuneTable(_Table):
    """``[tune]`` (``agv-cosim tune``, docs/tune.md): the objective (a metric of
    ``[metrics]``, or metric -> weight summed), its aggregate over the runs, the
    optimiser and its budget, and the bounded parameters; names are checked against the
    runs by :mod:`agv_cosim.tuning`."""

    objective: StrictStr | Annotated[dict[str, Number], Field(min_length=1)]
    aggregate: Literal["mean", "worst"] = "mean"
    method: Literal["evolution", "gradient"] = "evolution"
    generations: Annotated[StrictInt, Field(ge=1, le=10_000)] = 30
    popsize: Annotated[StrictInt, Field(ge=1, le=1_000)] = 10
    seed: Annotated[StrictInt, Field(ge=0)] = 0
    tol: Annotated[Number, Field(ge=0)] = 1e-6
    parameters: Annotated[dict[Annotated[StrictStr, _dotted("component.parameter")],
                               Bounds], Field(min_length=1)]


class FitTable(_Table):
    """``[fit]`` (``agv-cosim fit``, docs/fit.md): the measured data, the signals fitted
    to its columns, their weights and the fitted parameters; names are checked against
    the run's FMUs and the data by :mod:`agv_cosim.manifest_fit.checks`."""

    data: StrictStr
    signals: Annotated[dict[Dotted, StrictStr], Field(min_length=1)]
    weights: dict[Dotted, Number] = {}
    parameters: Annotated[dict[Annotated[StrictStr, _dotted("component.parameter")],
                               Bounds], Field(min_length=1)]


class ManifestTable(_Table):
    """The top level of a manifest."""

    name: StrictStr | None = None
    description: StrictStr = ""
    simulation: Simulation
    components: Annotated[dict[str, ComponentTable], Field(min_length=1)]
    connections: list[ConnectionTable] = []
    #: inputs left unconnected on purpose ("component.input"): held at their start
    #: values without the unconnected-inputs warning (checked in :mod:`agv_cosim.system`)
    held: list[Dotted] = []
    variants: dict[str, VariantTable] = {}
    sweep: dict[str, Annotated[list[Any], Field(min_length=1)]] = {}
    record: RecordTable = RecordTable()
    events: dict[str, EventTable] = {}
    metrics: MetricsTable = MetricsTable()
    plots: PlotsTable = PlotsTable()
    montecarlo: MonteCarloTable | None = None
    tune: TuneTable | None = None
    fit: FitTable | None = None


# --------------------------------------------------------------------------- errors

def check(model: type[M], data: Any, prefix: str = "") -> M:
    """``model`` validated from ``data``; else a :class:`SchemaError` for the first problem
    (the further ones in its ``others``), its key prefixed by ``prefix`` (e.g.
    ``"metrics"`` for a ``[metrics]`` table alone)."""
    try:
        return model.model_validate(data)
    except ValidationError as error:
        problems = schema_errors(model, error, prefix)
        first = problems[0]
        first.others = problems[1:]
        raise first from None


def schema_error(model: type[BaseModel], error: ValidationError,
                 prefix: str = "") -> SchemaError:
    """The first error of a pydantic ``ValidationError`` as a :class:`SchemaError`."""
    return schema_errors(model, error, prefix)[0]


def schema_errors(model: type[BaseModel], error: ValidationError,
                  prefix: str = "") -> list[SchemaError]:
    """Every error of a pydantic ``ValidationError`` as a :class:`SchemaError`, in
    pydantic's order. An unknown key close to a known one of the same table is named with
    it ("did you mean"), and that key's "missing" (the symptom of the misspelling) is
    dropped."""
    errors = error.errors()
    misspelt = set()
    found = []
    for one in errors:
        parts, parent = _walk(model, one["loc"])
        problem = _problem(one, parent)
        if one["type"] == "extra_forbidden" and parent is not None:
            name = str(parts[-1])
            allowed = _allowed(parent)
            match = closest(name, allowed)
            what = "section" if isinstance(one.get("input"), (dict, list)) else "key"
            if match is not None:
                misspelt.add(tuple(one["loc"][:-1]) + (match,))
                problem = f"unknown {what} '{name}' (did you mean '{match}'?)"
            else:
                problem = f"unknown {what} '{name}' (allowed: {', '.join(allowed)})"
        if one["type"] in ("union_tag_invalid", "union_tag_not_found"):
            parts.append(one["ctx"]["discriminator"].strip("'"))
        found.append((one, parts, problem))
    out = []
    for one, parts, problem in found:
        if one["type"] == "missing" and tuple(one["loc"]) in misspelt:
            continue
        key = prefix
        for part in parts:
            key += f"[{part}]" if isinstance(part, int) else (f".{part}" if key else str(part))
        out.append(SchemaError(key or "(top level)", problem))
    return out


def _allowed(parent: type[BaseModel]) -> list[str]:
    return [f.alias or n for n, f in parent.model_fields.items()]


def _problem(error: ErrorDetails, parent: type[BaseModel] | None) -> str:
    kind, value, ctx = error["type"], error.get("input"), error.get("ctx", {})
    if kind == "extra_forbidden":
        allowed = _allowed(parent) if parent else []
        return "unknown key" + (f" (allowed: {', '.join(allowed)})" if allowed else "")
    if kind == "missing":
        return "missing"
    if kind == "value_error":
        return str(ctx.get("error", error["msg"]))
    texts = {
        "float_type": f"{value!r} is not a number",
        "int_type": f"{value!r} is not an integer",
        "string_type": f"{value!r} is not a string",
        "finite_number": f"{value!r} is not finite",
        "dict_type": f"must be a table, not {type(value).__name__}",
        "model_type": f"must be a table, not {type(value).__name__}",
        "model_attributes_type": f"must be a table, not {type(value).__name__}",
        "list_type": f"must be an array, not {type(value).__name__}",
        "too_short": "must not be empty",
        "literal_error": f"{value!r} is not one of {_names(ctx.get('expected'))}"
                         f"{_suggest(value, ctx.get('expected'))}",
        "union_tag_invalid": f"{ctx.get('tag')!r} is not one of "
                             f"{_names(ctx.get('expected_tags'))}",
        "union_tag_not_found": "missing",
    }
    for bound, relation in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<=")):
        if bound in ctx:
            limit = ctx[bound]
            if isinstance(limit, float) and limit.is_integer():
                limit = int(limit)
            return f"{value!r} must be {relation} {limit}"
    return texts.get(kind, f"{value!r}: {error['msg']}")


def _suggest(value: object, expected: object) -> str:
    """" (did you mean 'x'?)" for a string close to one of pydantic's expected values."""
    if not isinstance(value, str) or not expected:
        return ""
    return did_you_mean(value, _names(expected).split(", "))


def _names(expected: object) -> str:
    """pydantic's ``'a', 'b' or 'c'`` as ``a, b, c``."""
    return str(expected).replace("'", "").replace(" or ", ", ")


def _unwrap(annotation: Any) -> Any:
    """``annotation`` without Annotated and Optional; a union of models stays a tuple."""
    while True:
        origin = typing.get_origin(annotation)
        if origin is Annotated:
            annotation = typing.get_args(annotation)[0]
        elif origin in (typing.Union, types.UnionType):
            members = [a for a in typing.get_args(annotation) if a is not type(None)]
            if len(members) > 1:
                return tuple(members)
            annotation = members[0]
        else:
            return annotation


def _is_model(annotation: object) -> TypeGuard[type[BaseModel]]:
    return isinstance(annotation, type) and issubclass(annotation, BaseModel)


def _walk(model: type[BaseModel], loc: tuple[int | str, ...]
          ) -> tuple[list[int | str], type[BaseModel] | None]:
    """Follow pydantic's ``loc`` down from ``model``: the parts that name keys (without
    "[key]" and the tags of tagged unions) and the model holding the last key (or None)."""
    annotation: Any = model
    parts: list[int | str] = []
    parent: type[BaseModel] | None = None
    for part in loc:
        annotation = _unwrap(annotation)
        if part == "[key]":
            continue
        if isinstance(annotation, tuple):  # a tagged union: ``part`` is the tag
            annotation = next((m for m in annotation if _is_model(m) and any(
                typing.get_origin(f.annotation) is Literal and part in
                typing.get_args(f.annotation) for f in m.model_fields.values())), None)
            continue
        parts.append(part)
        if _is_model(annotation):
            parent = annotation
            field = next((f for n, f in annotation.model_fields.items()
                          if (f.alias or n) == part), None)
            annotation = field.annotation if field else None
        else:
            parent = None
            origin = typing.get_origin(annotation)
            annotation = typing.get_args(annotation)[-1] if origin in (dict, list) else None
    return parts, parent
