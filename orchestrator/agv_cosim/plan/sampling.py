"""Monte Carlo runs of a manifest: the ``[montecarlo]`` table sampled into runs.

A manifest with a ``[montecarlo]`` table runs ``samples`` runs per variant (and per sweep
point), each with parameter values drawn from the distributions given, and writes, beside
the usual per-run folders and ``summary.csv`` (which gets one column per sampled
parameter and the sample index), ``montecarlo.json`` (per group, per metric: mean, std,
p5 / p50 / p95, failures, n) and ``montecarlo.png`` (box plots of the key metrics per
group, and the p5-p95 band and median of one signal over time per group).

The table
---------
::

    [montecarlo]
    samples = 32                 # runs per variant (x sweep point), >= 1
    seed = 2026                  # master seed, an integer >= 0
    design = "random"            # "random" (default), "sobol" or "lhs" (scipy.stats.qmc)
    seeds = ["ts.seed", "gyro.seed"]   # integer parameters given a seed of their own per run
    metrics = ["lateral_error_settled_max"]  # box plots (default: the first 4 metrics)
    band = "truth.lateral_error"  # signal drawn as p5-p95 band + median (optional)

    [montecarlo.parameters]
    "ts.jitter"  = { distribution = "uniform", low = 0.0, high = 0.3 }
    "ts.noise"   = { distribution = "normal", mean = 0.003, std = 0.001 }
    "ts.latency" = { distribution = "truncnormal", mean = 0.1, std = 0.05, low = 0.0, high = 0.3 }
    "ts.mean_interval" = { distribution = "choice", values = [0.3, 0.65], weights = [1, 3] }

How the numbers are drawn
-------------------------
Every design first draws ``samples`` points of the unit cube [0, 1)^d (d = the number of
sampled parameters, in manifest order): ``random`` with ``numpy.random.default_rng``,
``sobol`` with a scrambled ``scipy.stats.qmc.Sobol`` (balanced when ``samples`` is a power
of 2), ``lhs`` with ``scipy.stats.qmc.LatinHypercube``; then each coordinate goes through
its distribution's inverse CDF (ppf): ``normal`` (``scipy.stats.norm``), ``uniform``
(low + u (high - low)), ``truncnormal`` (``scipy.stats.truncnorm``, mean / std of the
untruncated normal, bounds low <= x <= high), ``choice`` (the value whose cumulative
weight first exceeds u; equal weights by default).

Seeds. From ``SeedSequence(seed)`` two children are spawned: the first draws the design,
the second spawns one child per sample index i; sample i's run seeds are
``child_i.generate_state(len(seeds)) >> 1`` (31-bit integers, so they fit an FMI Integer).
Both depend only on the master seed and the sample index (and for ``lhs`` on
``samples``), so a manifest gives the same numbers locally, on Dask, in any order.

Common random numbers. Sample i has the same parameter values and the same seeds in every
variant (and sweep point): the variants are compared on identical disturbances, so the
differences between them are not sampling noise.

Statistics (``montecarlo.json``): over the runs of a group that are ``complete`` and have
a finite value of the metric; every other run of the group counts as a failure of that
metric (``n + failures`` = runs of the group). ``std`` is the sample standard deviation
(ddof = 1; null for n < 2); the percentiles are ``numpy.percentile``'s linear ones.
"""

import copy
import math
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np

from ..errors import SamplingError
from ..manifest import Component, Manifest
from ..manifest.montecarlo import MonteCarlo
from .spec import Origin, RunSpec, run_label

__all__ = ["SAMPLE", "choice_edges", "draw", "expand_runs", "group_name", "ppf",
           "run_seeds", "unit_samples"]

#: Column of summary.csv (and key of a run's sweep point) holding the sample index.
SAMPLE = "montecarlo.sample"


def unit_samples(mc: MonteCarlo) -> np.ndarray:
    """The design's points of [0, 1)^d, shape (samples, d) (d = sampled parameters)."""
    design_seq, _ = np.random.SeedSequence(mc.seed).spawn(2)
    d = len(mc.parameters)
    if d == 0:
        return np.zeros((mc.samples, 0))
    rng = np.random.default_rng(design_seq)
    if mc.design == "random":
        return rng.random((mc.samples, d))
    from scipy.stats import qmc

    engine = (qmc.Sobol(d, scramble=True, seed=rng) if mc.design == "sobol"
              else qmc.LatinHypercube(d, seed=rng))
    with warnings.catch_warnings():  # Sobol: n not a power of 2 loses balance (documented)
        warnings.simplefilter("ignore", UserWarning)
        sample: np.ndarray = engine.random(mc.samples)
    return sample


def choice_edges(weights: Sequence[float] | np.ndarray) -> np.ndarray:
    """Cumulative weights normalised to end at 1 (the ``choice`` inverse CDF).

    Weights whose sum overflows a double (two of 1e308) are first scaled by the largest
    one, which keeps their ratios; other weights are used as given.
    """
    array = np.asarray(weights, dtype=float)
    with np.errstate(over="ignore"):
        total = array.sum()
    if not np.isfinite(total):
        array = array / array.max()
        total = array.sum()
    edges: np.ndarray = np.cumsum(array) / total
    edges[-1] = 1.0  # the last edge is 1 whatever the rounding of the sum
    return edges


def ppf(spec: dict[str, Any], u: Sequence[float] | np.ndarray) -> list[Any]:
    """Map uniforms ``u`` (array in [0, 1)) through a distribution's inverse CDF.

    Returns a list of plain Python values (floats, or the choice's values).

    Raises
    ------
    SamplingError
        When the distribution's numbers overflow a double: a uniform whose width
        ``high - low`` does, a normal whose samples do, a truncated normal whose bounds
        are so many standard deviations from the mean (beyond ~1e154) that
        ``scipy.stats.truncnorm`` cannot compute it. Such a table is refused, never
        clipped into wrong values.
    """
    from scipy import stats

    u = np.asarray(u, dtype=float)
    kind = spec["distribution"]
    if kind == "choice":
        edges = choice_edges(spec.get("weights") or [1.0] * len(spec["values"]))
        index = np.minimum(np.searchsorted(edges, u, side="right"), len(edges) - 1)
        return [spec["values"][i] for i in index]
    # u = 0 exactly (possible, 2**-53 per draw) would give -inf for a normal
    u = np.clip(u, np.finfo(float).tiny, 1.0 - np.finfo(float).eps / 2)
    with np.errstate(over="ignore", invalid="ignore"):
        if kind == "uniform":
            width = spec["high"] - spec["low"]
            if not math.isfinite(width):
                raise SamplingError(f"high - low = {spec['high']!r} - {spec['low']!r} "
                                    "overflows a double; give a narrower range")
            x = spec["low"] + u * width
        elif kind == "normal":
            x = stats.norm.ppf(u, loc=spec["mean"], scale=spec["std"])
        else:
            a = (spec["low"] - spec["mean"]) / spec["std"]
            b = (spec["high"] - spec["mean"]) / spec["std"]
            # scipy's own tail handling, checked: a bound too far out (a * a overflows)
            # gives inf, which must not be clipped into the opposite bound
            x = stats.truncnorm.ppf(u, a, b, loc=spec["mean"], scale=spec["std"])
            if np.all(np.isfinite(x)):
                x = np.clip(x, spec["low"], spec["high"])
            elif np.isfinite(a) and np.isfinite(b) and max(abs(a), abs(b)) < 1e150:
                raise SamplingError("the samples overflow a double")
            else:
                raise SamplingError(f"the bounds are {min(abs(a), abs(b)):.3g} standard "
                                    "deviations from the mean, beyond what "
                                    "scipy.stats.truncnorm computes; the distribution is "
                                    "all at one bound (give that value instead)")
    if not np.all(np.isfinite(x)):
        bad = float(x[~np.isfinite(x)][0])
        raise SamplingError(f"a sample is {bad!r}: the distribution's numbers overflow a "
                            "double")
    return [float(v) for v in x]


def run_seeds(mc: MonteCarlo) -> list[dict[str, int]]:
    """Per sample index, the derived seed of each ``seeds`` parameter (list of dicts)."""
    _, runs_seq = np.random.SeedSequence(mc.seed).spawn(2)
    return [{name: int(value >> 1) for name, value in
             zip(mc.seeds, child.generate_state(len(mc.seeds), dtype=np.uint32))}
            for child in runs_seq.spawn(mc.samples)] if mc.seeds else \
        [{} for _ in range(mc.samples)]


def draw(mc: MonteCarlo) -> list[dict[str, Any]]:
    """The sampled values: a list (one per sample index) of {"comp.param": value}."""
    u = unit_samples(mc)
    columns = {}
    for j, (name, spec) in enumerate(mc.parameters.items()):
        try:
            columns[name] = ppf(spec, u[:, j])
        except SamplingError as error:
            raise SamplingError(f"parameters.{name}: {spec['distribution']}: {error}") \
                from None
    seeds = run_seeds(mc)
    return [{**{name: columns[name][i] for name in mc.parameters}, **seeds[i]}
            for i in range(mc.samples)]


def expand_runs(manifest: Manifest, runs: list[RunSpec]) -> list[RunSpec]:
    """Each run (variant x sweep point) repeated for every sample, values applied.

    The sample's values go into the run's parameters (after ``--set``; a ``--set`` on a
    sampled parameter is an error) and into its ``point`` (so summary.csv lists them),
    with the sample index under :data:`SAMPLE`.
    """
    mc = manifest.montecarlo
    if mc is None:
        return runs
    try:
        values = draw(mc)
    except SamplingError as error:
        key, _, problem = str(error).partition(": ")
        raise manifest.error(f"montecarlo.{key}", problem) from None
    width = max(4, len(str(mc.samples - 1)))
    expanded = []
    for run in runs:
        for name in run.overrides:
            if name in mc.names:
                raise manifest.error("--set", f"'{name}' is also sampled in "
                                    "[montecarlo]")
        base = [run.variant or "base"] + [f"{k}={v!r}" for k, v in run.point.items()]
        for index, sample in enumerate(values):
            comps = {cname: _copy_component(comp) for cname, comp in run.components.items()}
            origins = dict(run.origins)
            for name, value in sample.items():
                cname, _, pname = name.partition(".")
                if cname not in comps:
                    key = "parameters." + name if name in mc.parameters else "seeds"
                    raise manifest.error(f"montecarlo.{key}", f"variant '{run.variant}' "
                                         f"has no component '{cname}' (it removes it or "
                                         "the base has none)")
                comps[cname].parameters[pname] = value
                origins[name] = Origin.MONTECARLO
            point = dict(run.point)
            point[SAMPLE] = index
            point.update(sample)
            expanded.append(type(run)(label=run_label(base + [f"mc{index:0{width}d}"]),
                                      variant=run.variant, point=point, components=comps,
                                      overrides=run.overrides,
                                      connections=run.connections, events=run.events,
                                      spec=run.spec, origins=origins))
    return expanded


def _copy_component(comp: Component) -> Component:
    copy_ = copy.copy(comp)
    copy_.parameters = dict(comp.parameters)
    return copy_


def group_name(variant: str | None, point: dict[str, Any]) -> str:
    """The name of a run's group: its variant and sweep point, without the sample (the
    sweep values come before :data:`SAMPLE` in the point, the sampled ones after it)."""
    keys = list(point)
    sweep = keys[:keys.index(SAMPLE)] if SAMPLE in keys else keys
    return run_label([variant or "base"] + [f"{k}={point[k]!r}" for k in sweep])


