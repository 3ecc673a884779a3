"""The first three stages in one call: a manifest loaded, planned and checked into the
self-contained :class:`~agv_cosim.system.Job` of each run."""

from collections.abc import Iterable
from pathlib import Path
from typing import Any

from .. import fmitypes
from ..manifest import Manifest, load_manifest
from ..plan import plan_runs
from ..report import metrics, plots
from ..system import Job, System, Variable, validate

__all__ = ["prepare"]


def _start_value(var: Variable) -> Any:
    if var.start is None or var.unsupported():
        return None
    try:
        return fmitypes.parse_text(var.ftype, var.start)
    except ValueError:
        return var.start


def _signal_sources(manifest: Manifest) -> list[tuple[str, list[str]]]:
    sources = []
    for name, spec, module in (("metrics", manifest.metrics, metrics),
                               ("plots", manifest.plots, plots)):
        if spec:
            try:
                sources.append((name, list(module.referenced_signals(spec))))
            except Exception as error:  # noqa: BLE001 - a bad spec is a manifest error
                raise manifest.error(name, str(error)) from None
    # a path string is checked now, not after the runs (it would leave metrics empty)
    base_dir = Path(manifest.path).parent
    reference = manifest.metrics.reference if manifest.metrics else None
    trajectory = manifest.plots.trajectory if manifest.plots else None
    for key, text in (("metrics.reference.path", reference.path if reference else None),
                      ("plots.trajectory.path", trajectory.path if trajectory else None)):
        if isinstance(text, str):
            try:
                metrics.load_path(text, key, base_dir)
            except Exception as error:  # noqa: BLE001 - a bad path is a manifest error
                problem = str(error).removeprefix(f"{key}: ")
                raise manifest.error(key, problem) from None
    return sources


def prepare(manifest: str | Path | Manifest, variants: list[str] | None = None,
            sets: Iterable[str] = (),
            timeout: float | None = None) -> tuple[Manifest, list[Job], list[str]]:
    """Load, plan and check a manifest into its jobs.

    ``manifest``: a manifest file, or a :class:`~agv_cosim.manifest.Manifest` already
    loaded (an SSP package read by :func:`agv_cosim.ssp.importer.opened`: messages and
    run.json then name the package, its SHA-256, and its FMUs as
    ``<package>!/<path inside it>``). ``timeout``: each run's wall-clock limit [s],
    instead of the manifest's ``[simulation] timeout``.

    Returns
    -------
    (Manifest, list of Job, list of str)
        The manifest, its jobs and the validation warnings.

    Raises
    ------
    ManifestError
    """
    if not isinstance(manifest, Manifest):
        manifest = load_manifest(manifest)
    runs = plan_runs(manifest, variants, sets)
    checked = validate(manifest, runs, _signal_sources(manifest))
    jobs = []
    for one in checked.runs:
        run, models = one.run, one.models
        effective = {c: {v.name: one.parameters[c].get(v.name, _start_value(v))
                         for v in info.parameters} for c, info in models.items()}
        system = System(models=models, parameters=one.parameters,
                        connections=run.connections, order=one.order,
                        record=one.record, start=manifest.start, stop=manifest.stop,
                        step=manifest.step, algorithm=manifest.algorithm,
                        record_every=manifest.record_every, steps=manifest.steps,
                        events=one.events)
        jobs.append(Job(label=run.label, variant=run.variant, point=run.point, plan=system,
                        parameters=effective,
                        fmu_sha256={c: info.sha256 for c, info in models.items()},
                        manifest_path=str(manifest.path), manifest_sha256=manifest.sha256,
                        metrics_spec=manifest.metrics,
                        fmu_paths={c: _shown_path(info.path, manifest)
                                   for c, info in models.items()},
                        timeout=manifest.timeout if timeout is None else timeout))
    return manifest, jobs, checked.warnings


def _shown_path(path: str | Path, manifest: Manifest) -> str:
    """How run.json names an FMU: inside an unpacked .ssp as ``<ssp>!/<entry>``."""
    if manifest.unpacked is not None and manifest.unpacked in Path(path).parents:
        return f"{manifest.path}!/{Path(path).relative_to(manifest.unpacked).as_posix()}"
    return str(path)
