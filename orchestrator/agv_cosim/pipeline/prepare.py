"""The first three stages in one call: a manifest loaded, planned and checked into the
self-contained :class:`~agv_cosim.system.Job` of each run."""

import os
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path
from typing import Any

from .. import fmitypes
from ..manifest import Manifest, load_manifest
from ..manifest.load import component_steps
from ..plan import Experiment, Override, plan_runs
from ..report import metrics, plots
from ..system import CheckedRun, Event, Job, System, Variable, validate
from ..system.files import hash_files, resolved

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
    # a path string is checked now, not after the runs (it would leave metrics empty);
    # its files are read from where the parameters' are (agv_cosim.system.files)
    base_dir = manifest.files_dir
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
            sets: Iterable[str | Override] = (),
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
    checked = validate(Experiment.of(manifest), runs, _signal_sources(manifest))
    jobs = []
    hashes: dict[Path, str] = {}
    for one in checked.runs:
        run, models = one.run, one.models
        effective = {c: {v.name: one.parameters[c].get(v.name, _start_value(v))
                         for v in info.parameters} for c, info in models.items()}
        parameters, events, files = _with_files(manifest, one, hashes)
        system = System(models=models, parameters=parameters,
                        connections=run.connections, order=one.order,
                        record=one.record, start=manifest.start, stop=manifest.stop,
                        step=manifest.step, algorithm=manifest.algorithm,
                        record_every=manifest.record_every, steps=manifest.steps,
                        events=events,
                        component_steps=component_steps(run.components, manifest.step))
        jobs.append(Job(label=run.label, variant=run.variant, point=run.point, plan=system,
                        parameters=effective,
                        fmu_sha256={c: info.sha256 for c, info in models.items()},
                        manifest_path=os.path.abspath(manifest.path),
                        manifest_sha256=manifest.sha256,
                        metrics_spec=manifest.metrics,
                        fmu_paths={c: _shown_path(info.path, manifest)
                                   for c, info in models.items()},
                        timeout=manifest.timeout if timeout is None else timeout,
                        base_dir=manifest.files_dir, files=files))
    return manifest, jobs, checked.warnings


def _with_files(manifest: Manifest, one: CheckedRun, hashes: dict[Path, str]
                ) -> tuple[dict[str, dict[str, Any]], list[Event], dict[str, dict[str, str]]]:
    """The run's parameters and events as its FMUs are given them (each file a value
    names made absolute, :func:`~agv_cosim.system.files.resolved`), and the files'
    SHA-256 (:func:`~agv_cosim.system.files.hash_files`; ``hashes`` caches them by path).
    The check of the run found every file readable: one that is not now is a
    :class:`ManifestError` of the manifest's ``components``."""
    base = manifest.files_dir
    named: dict[str, Any] = {}
    parameters = {}
    for cname, values in one.parameters.items():
        parameters[cname] = {pname: resolved(value, base) for pname, value in values.items()}
        named.update({f"{cname}.{pname}": value for pname, value in values.items()})
    events = []
    for event in one.events:
        sets = tuple((c, v, resolved(value, base)) for c, v, value in event.sets)
        events.append(replace(event, sets=sets))
        named.update({f"events.{event.name}.{c}.{v}": value for c, v, value in event.sets})
    try:
        files = hash_files(named, base, hashes)
    except OSError as error:
        raise manifest.error("components", f"cannot read '{error.filename}': "
                             f"{error.strerror or error}") from None
    return parameters, events, files


def _shown_path(path: str | Path, manifest: Manifest) -> str:
    """How run.json names an FMU: inside an unpacked .ssp as ``<ssp>!/<entry>`` (the
    package's absolute path, as run.json names the manifest: the same from any current
    folder)."""
    if manifest.unpacked is not None and manifest.unpacked in Path(path).parents:
        entry = Path(path).relative_to(manifest.unpacked).as_posix()
        return f"{os.path.abspath(manifest.path)}!/{entry}"
    return str(path)
