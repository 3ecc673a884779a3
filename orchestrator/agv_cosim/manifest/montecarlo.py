"""The ``[montecarlo]`` table of a manifest, checked into a :class:`MonteCarlo`.

How the table is sampled into runs is :mod:`agv_cosim.plan.sampling`; the statistics and
figure over the runs are :mod:`agv_cosim.report.montecarlo`.
"""

from collections.abc import Collection
from typing import Any

from ..errors import ManifestError, SchemaError, did_you_mean
from . import schema

__all__ = ["DESIGNS", "DISTRIBUTIONS", "MonteCarlo", "parse"]

DESIGNS = ("random", "sobol", "lhs")
DISTRIBUTIONS = {
    "normal": ("mean", "std"),
    "uniform": ("low", "high"),
    "truncnormal": ("mean", "std", "low", "high"),
    "choice": ("values",),
}
class MonteCarlo:
    """A checked ``[montecarlo]`` table (see the module docstring)."""

    def __init__(self, samples: int, seed: int, design: str,
                 parameters: dict[str, dict[str, Any]], seeds: list[str],
                 metrics: list[str] | None, band: str | None) -> None:
        self.samples, self.seed, self.design = samples, seed, design
        self.parameters = parameters  # "comp.param" -> {"distribution": ..., ...}
        self.seeds, self.metrics, self.band = seeds, metrics, band

    @property
    def names(self) -> list[str]:
        return list(self.parameters) + list(self.seeds)

    def describe(self) -> dict[str, Any]:
        return {"samples": self.samples, "seed": self.seed, "design": self.design,
                "parameters": self.parameters, "seeds": self.seeds}


def _error(path: object, key: str, problem: str) -> ManifestError:
    return ManifestError(path, f"montecarlo.{key}" if key else "montecarlo", problem)


def parse(path: object, table: Any, components: Collection[str] = (),
          swept: Collection[str] = ()) -> MonteCarlo | None:
    """Check a raw ``[montecarlo]`` TOML table; return a :class:`MonteCarlo` or None.

    Its shape is :class:`agv_cosim.schema.MonteCarloTable`; here the names:
    ``components``, the manifest's component names; ``swept``, its swept names (a
    parameter is sampled or swept, not both).

    Raises
    ------
    ManifestError
        Naming the key (``montecarlo.<key>``) and the problem.
    """
    if table is None:
        return None
    try:
        checked = schema.check(schema.MonteCarloTable, table, "montecarlo")
    except SchemaError as error:
        raise ManifestError(path, error.key, error.problem) from None
    parameters = {}
    for name, spec in checked.parameters.items():
        key = f"parameters.{name}"
        cname, dot, rest = name.partition(".")
        if not cname or not rest:
            raise _error(path, key, f"{name!r} is not of the form 'component.parameter'")
        if components and cname not in components:
            raise _error(path, key, f"unknown component '{cname}'"
                         f"{did_you_mean(cname, components)}")
        if name in swept:
            raise _error(path, key, f"'{name}' is also swept in [sweep]")
        kind = spec.distribution  # keys in the documented order (montecarlo.json)
        parameters[name] = {"distribution": kind, **{
            sub: getattr(spec, sub) for sub in DISTRIBUTIONS[kind] + ("weights",)
            if getattr(spec, sub, None) is not None}}
    seeds = checked.seeds
    for name in seeds:
        cname = name.partition(".")[0]
        if components and cname not in components:
            raise _error(path, "seeds", f"unknown component '{cname}' in '{name}'"
                         f"{did_you_mean(cname, components)}")
        if name in parameters or name in swept or seeds.count(name) > 1:
            raise _error(path, "seeds", f"'{name}' is listed twice (seeds, parameters or "
                         "sweep)")
    if not parameters and not seeds:
        raise _error(path, "parameters", "nothing to sample: give parameters or seeds")
    return MonteCarlo(checked.samples, checked.seed, checked.design, parameters, list(seeds),
                      checked.metrics, checked.band)


