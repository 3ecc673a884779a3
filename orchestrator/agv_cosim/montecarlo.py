"""Monte Carlo runs of a manifest: the ``[montecarlo]`` table, sampling and statistics.

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

import csv
import math
import warnings
from pathlib import Path

import numpy as np

from . import schema
from .manifest import ManifestError
from .plan import run_label

DESIGNS = ("random", "sobol", "lhs")
DISTRIBUTIONS = {
    "normal": ("mean", "std"),
    "uniform": ("low", "high"),
    "truncnormal": ("mean", "std", "low", "high"),
    "choice": ("values",),
}
#: Column of summary.csv (and key of a run's sweep point) holding the sample index.
SAMPLE = "montecarlo.sample"


class MonteCarlo:
    """A checked ``[montecarlo]`` table (see the module docstring)."""

    def __init__(self, samples, seed, design, parameters, seeds, metrics, band):
        self.samples, self.seed, self.design = samples, seed, design
        self.parameters = parameters  # "comp.param" -> {"distribution": ..., ...}
        self.seeds, self.metrics, self.band = seeds, metrics, band

    @property
    def names(self):
        return list(self.parameters) + list(self.seeds)

    def describe(self):
        return {"samples": self.samples, "seed": self.seed, "design": self.design,
                "parameters": self.parameters, "seeds": self.seeds}


def _error(path, key, problem):
    return ManifestError(path, f"montecarlo.{key}" if key else "montecarlo", problem)


def parse(path, table, components=(), swept=()):
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
    except schema.SchemaError as error:
        raise ManifestError(path, error.key, error.problem) from None
    parameters = {}
    for name, spec in checked.parameters.items():
        key = f"parameters.{name}"
        cname, dot, rest = name.partition(".")
        if not cname or not rest:
            raise _error(path, key, f"{name!r} is not of the form 'component.parameter'")
        if components and cname not in components:
            raise _error(path, key, f"unknown component '{cname}'")
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
            raise _error(path, "seeds", f"unknown component '{cname}' in '{name}'")
        if name in parameters or name in swept or seeds.count(name) > 1:
            raise _error(path, "seeds", f"'{name}' is listed twice (seeds, parameters or "
                         "sweep)")
    if not parameters and not seeds:
        raise _error(path, "parameters", "nothing to sample: give parameters or seeds")
    return MonteCarlo(checked.samples, checked.seed, checked.design, parameters, list(seeds),
                      checked.metrics, checked.band)


def unit_samples(mc):
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
        return engine.random(mc.samples)


class SamplingError(ValueError):
    """A distribution whose numbers a double cannot hold (the text says which)."""


def choice_edges(weights):
    """Cumulative weights normalised to end at 1 (the ``choice`` inverse CDF).

    Weights whose sum overflows a double (two of 1e308) are first scaled by the largest
    one, which keeps their ratios; other weights are used as given.
    """
    weights = np.asarray(weights, dtype=float)
    with np.errstate(over="ignore"):
        total = weights.sum()
    if not np.isfinite(total):
        weights = weights / weights.max()
        total = weights.sum()
    edges = np.cumsum(weights) / total
    edges[-1] = 1.0  # the last edge is 1 whatever the rounding of the sum
    return edges


def ppf(spec, u):
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


def run_seeds(mc):
    """Per sample index, the derived seed of each ``seeds`` parameter (list of dicts)."""
    _, runs_seq = np.random.SeedSequence(mc.seed).spawn(2)
    return [{name: int(value >> 1) for name, value in
             zip(mc.seeds, child.generate_state(len(mc.seeds), dtype=np.uint32))}
            for child in runs_seq.spawn(mc.samples)] if mc.seeds else \
        [{} for _ in range(mc.samples)]


def draw(mc):
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


def expand_runs(manifest, runs):
    """Each run (variant x sweep point) repeated for every sample, values applied.

    The sample's values go into the run's parameters (after ``--set``; a ``--set`` on a
    sampled parameter is an error) and into its ``point`` (so summary.csv lists them),
    with the sample index under :data:`SAMPLE`.
    """
    mc = manifest.montecarlo
    try:
        values = draw(mc)
    except SamplingError as error:
        key, _, problem = str(error).partition(": ")
        raise _error(manifest.path, key, problem) from None
    width = max(4, len(str(mc.samples - 1)))
    expanded = []
    for run in runs:
        for name in run.overrides:
            if name in mc.names:
                raise ManifestError(manifest.path, "--set", f"'{name}' is also sampled in "
                                    "[montecarlo]")
        base = [run.variant or "base"] + [f"{k}={v!r}" for k, v in run.point.items()]
        for index, sample in enumerate(values):
            comps = {cname: _copy_component(comp) for cname, comp in run.components.items()}
            for name, value in sample.items():
                cname, _, pname = name.partition(".")
                comps[cname].parameters[pname] = value
            point = dict(run.point)
            point[SAMPLE] = index
            point.update(sample)
            expanded.append(type(run)(label=run_label(base + [f"mc{index:0{width}d}"]),
                                      variant=run.variant, point=point, components=comps,
                                      overrides=run.overrides, events=run.events))
    return expanded


def _copy_component(comp):
    import copy

    copy_ = copy.copy(comp)
    copy_.parameters = dict(comp.parameters)
    return copy_


def group_name(variant, point):
    """The name of a run's group: its variant and sweep point, without the sample (the
    sweep values come before :data:`SAMPLE` in the point, the sampled ones after it)."""
    keys = list(point)
    sweep = keys[:keys.index(SAMPLE)] if SAMPLE in keys else keys
    return run_label([variant or "base"] + [f"{k}={point[k]!r}" for k in sweep])


def statistics(values, runs):
    """mean, std (ddof 1), p5, p50, p95, n, failures of finite ``values`` of ``runs``."""
    data = np.asarray([v for v in values if v is not None and math.isfinite(v)], float)
    n = int(data.size)
    out = {"n": n, "failures": runs - n, "mean": None, "std": None, "p5": None,
           "p50": None, "p95": None, "min": None, "max": None}
    if n:
        p5, p50, p95 = np.percentile(data, [5, 50, 95])
        out.update(mean=float(data.mean()), p5=float(p5), p50=float(p50),
                   p95=float(p95), min=float(data.min()), max=float(data.max()))
        if n > 1:
            out["std"] = float(data.std(ddof=1))
    return out


def _groups(jobs, results):
    groups = {}
    for job, result in zip(jobs, results):
        groups.setdefault(group_name(job.variant, job.point), []).append((job, result))
    return groups


def aggregate(mc, jobs, results):
    """The content of ``montecarlo.json`` (see the module docstring)."""
    out = {**mc.describe(), "groups": {}}
    for name, members in _groups(jobs, results).items():
        names = []
        for _, result in members:
            for metric in result["metrics"]:
                if metric not in names:
                    names.append(metric)
        complete = [r for _, r in members if r["status"] == "complete"]
        out["groups"][name] = {
            "variant": members[0][0].variant, "runs": len(members),
            "failed_runs": len(members) - len(complete),
            "metrics": {m: statistics([_number(r["metrics"].get(m)) for r in complete],
                                      len(members)) for m in names}}
    return out


def _number(value):
    return float(value) if isinstance(value, (int, float)) and \
        not isinstance(value, bool) else None


def _band(folder, members, signal):
    """Time and (p5, p50, p95) of ``signal`` over the group's complete runs."""
    series, time = [], None
    for job, result in members:
        if result["status"] != "complete":
            continue
        path = Path(folder) / job.label / "timeseries.csv"
        with open(path, encoding="utf-8", newline="") as stream:
            reader = csv.reader(stream)
            header = next(reader)
            column = header.index(signal)
            rows = [(float(row[0]), float(row[column])) for row in reader]
        t = [r[0] for r in rows]
        if time is None or len(t) < len(time):
            time = t
        series.append([r[1] for r in rows])
    if not series:
        return None
    k = len(time)
    data = np.asarray([s[:k] for s in series])
    return np.asarray(time), np.percentile(data, [5, 50, 95], axis=0)


def figure(mc, jobs, results, folder, title=None, dpi=110):
    """``montecarlo.png``: box plots of the key metrics per group; the band of a signal."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    groups = _groups(jobs, results)
    names = mc.metrics
    if names is None:
        names = []
        for result in results:
            for metric in result["metrics"]:
                if metric not in names and len(names) < 4:
                    names.append(metric)
    panels = len(names) + (1 if mc.band else 0)
    if not panels:
        return None
    fig = Figure(figsize=(8.0, 2.6 * panels), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(panels, 1, squeeze=False)[:, 0]
    labels = list(groups)
    for ax, metric in zip(axes, names):
        data = [[v for v in (_number(r["metrics"].get(metric)) for _, r in members
                             if r["status"] == "complete") if v is not None and
                 math.isfinite(v)] for members in groups.values()]
        shown = [(label, d) for label, d in zip(labels, data) if d]
        if shown:
            ax.boxplot([d for _, d in shown], whis=(5, 95), orientation="horizontal")
            ax.set_yticks(range(1, len(shown) + 1), [label for label, _ in shown])
        ax.set_xlabel(metric)
        ax.grid(True, axis="x", alpha=0.3)
    if mc.band:
        ax = axes[-1]
        colours = [f"C{i % 10}" for i in range(len(groups))]
        for colour, (label, members) in zip(colours, groups.items()):
            band = _band(folder, members, mc.band)
            if band is None:
                continue
            t, (p5, p50, p95) = band
            ax.fill_between(t, p5, p95, color=colour, alpha=0.25, linewidth=0)
            ax.plot(t, p50, color=colour, label=f"{label}: median, p5-p95")
        ax.set_xlabel("time [s]")
        ax.set_ylabel(mc.band)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small", frameon=False)
    fig.suptitle((title + ": " if title else "") + f"{mc.samples} samples per group "
                 "(box: p25-p75, whiskers p5-p95)", fontsize="medium")
    from .results import open_output

    path = Path(folder) / "montecarlo.png"
    with open_output(path) as stream:  # never written through a symbolic link
        fig.savefig(stream, dpi=dpi, format="png", metadata={"Software": None})
    return path


def write_outputs(mc, jobs, results, folder, title=None):
    """Write ``montecarlo.json`` and ``montecarlo.png``; return a figure error or None."""
    from .results import write_json

    write_json(Path(folder) / "montecarlo.json", aggregate(mc, jobs, results))
    try:
        figure(mc, jobs, results, folder, title)
    except Exception as failure:  # noqa: BLE001 - a figure must not lose the results
        return f"{type(failure).__name__}: {failure}"
    return None
