"""The ``[fit]`` table of a manifest checked against its run, its FMUs and the
measured data, before any run (:func:`setup`, used by :mod:`.command`)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from ..fitting import MeasuredData, check_interval, read_data
from ..manifest import Manifest
from ..pipeline.prepare import prepare
from ..pipeline.trials import Tunable, signal_problem, tunable
from ..system import Job

__all__ = ["FitSetup", "setup"]


@dataclass
class FitSetup:
    """A fit checked and ready: the manifest, its one run (``job``), the parameters,
    the signals (signal -> column), the weights given, the data (and its file)."""

    manifest: Manifest
    job: Job
    parameters: list[Tunable]
    bounds: dict[str, tuple[float, float]]
    signals: dict[str, str]
    weights: dict[str, float]
    data: MeasuredData
    data_path: Path
    warnings: list[str]


def setup(manifest: str | Path | Manifest, variant: str | None = None) -> FitSetup:
    """The fit of ``manifest`` checked (see the module); ManifestError (a key of
    ``[fit]`` and its line) or FitDataError (the data file, line, column), one line."""
    loaded, jobs, warnings = prepare(manifest, [variant] if variant else None)
    spec = loaded.fit
    if spec is None:
        raise loaded.error("fit", "missing: a fit needs a [fit] table (data, signals, "
                           "parameters; docs/fit.md)")
    if len(jobs) != 1:
        raise loaded.error("fit", f"the manifest has {len(jobs)} runs (variants x sweep "
                           "points x samples); a fit needs one: choose a variant with "
                           "--variant, and no sweep or [montecarlo]")
    job = jobs[0]
    for signal in spec.signals:
        problem = signal_problem(job, signal)
        if problem is not None:
            raise loaded.error(f"fit.signals.{signal}", problem)
    for signal in spec.weights:
        if signal not in spec.signals:
            raise loaded.error(f"fit.weights.{signal}", "not a fitted signal (signals: "
                               f"{', '.join(spec.signals)})")
        if not spec.weights[signal] > 0:
            raise loaded.error(f"fit.weights.{signal}",
                               f"{spec.weights[signal]!r} must be > 0")
    parameters = tunable(loaded, [job], list(spec.parameters), "fit.parameters")
    bounds = {}
    for p in parameters:
        table = spec.parameters[p.name]
        key = f"fit.parameters.{p.name}"
        if not table.min < table.max:
            raise loaded.error(key, f"min {table.min!r} >= max {table.max!r}")
        if not table.min <= p.start <= table.max:
            raise loaded.error(key, f"start {p.start!r} (the run's value) is outside the "
                               f"bounds [{table.min!r}, {table.max!r}]")
        bounds[p.name] = (table.min, table.max)
    data_path = loaded.files_dir / spec.data
    data = read_data(data_path, list(dict.fromkeys(spec.signals.values())))
    check_interval(data, loaded.start, loaded.stop)
    return FitSetup(manifest=loaded, job=job, parameters=parameters, bounds=bounds,
                    signals=dict(spec.signals), weights=dict(spec.weights), data=data,
                    data_path=data_path, warnings=warnings)
