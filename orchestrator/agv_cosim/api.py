"""The Python API: run a manifest from a script or a notebook and read its results as
pandas DataFrames (docs/api.md).

:func:`run` does what ``agv-cosim run`` does (the same checks, the same result folder)
and returns :class:`Results`; :func:`open_results` reads a result folder written
before; :func:`identify` and :func:`fit` do what ``agv-cosim identify`` and
``agv-cosim fit`` do and return dicts. Every mistake and failure that the command
reports as an error raises :class:`~agv_cosim.errors.AgvCosimError`, whose text is
the command's line. A script needs no ``if __name__ == "__main__":`` guard: the worker
processes do not import the caller's main module. pandas is imported here only, when a
DataFrame is asked for.
"""

import csv
import io
import json
import math
import os
import sys
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from .errors import (
    AgvCosimError,
    ClusterError,
    FolderLost,
    ManifestError,
    ModelError,
    OutputError,
    ReportError,
    RunsStopped,
    UnreadableFile,
    error_lines,
    exit_code,
)
from .files import CSV_LIMIT, JSON_LIMIT, open_regular, printable, read_bytes, read_text

if TYPE_CHECKING:
    import pandas

    from .plan import Override

_T = TypeVar("_T")

__all__ = ["Results", "Run", "fit", "identify", "open_results", "run", "tune"]

_SUMMARY = "summary.csv"
_PARTIAL = "partial.txt"


@dataclass(frozen=True)
class Run:
    """One run of a result folder, as its ``run.json`` records it."""

    #: the run's label (its folder's name; summary.csv's ``run``)
    label: str
    #: complete, partial, failed, timed out, interrupted or not run
    status: str
    #: the run's folder (it may not exist for a run that never started)
    folder: Path
    #: why the run is not complete (None when it is)
    message: str | None
    variant: str | None = None
    #: the run's sweep values ("component.parameter" -> value)
    point: dict[str, Any] = field(default_factory=dict)
    #: rows of its timeseries.csv
    rows: int = 0
    #: why its metrics could not be computed (None: they were, or it has none)
    metrics_error: str | None = None
    #: the FMI interface each FMU component ran through ("co-simulation" or
    #: "model-exchange"; run.json's ``interfaces``)
    interfaces: dict[str, str] = field(default_factory=dict)
    #: each component integrated as Model Exchange -> ``{"solver": .., "tolerance": ..}``
    #: (run.json's ``integration``)
    integration: dict[str, dict[str, Any]] = field(default_factory=dict)


class Results:
    """A result folder of ``agv-cosim run`` (or :func:`run`), read on demand.

    ``warnings`` are the manifest's validation warnings when the folder was just written.
    """

    def __init__(self, folder: str | Path, warnings: Iterable[str] = ()) -> None:
        self.folder = Path(folder)
        self.warnings = list(warnings)
        summary = self.folder / _SUMMARY
        if not summary.is_file():
            what = "not found" if not self.folder.exists() else (
                f"not a result folder of agv-cosim run (no {_SUMMARY})")
            raise AgvCosimError(f"{self.folder}: {what}")
        self._runs: list[Run] | None = None

    def __repr__(self) -> str:
        runs = self.runs
        done = sum(r.status == "complete" for r in runs)
        mark = ", partial" if self.partial else ""
        return f"<Results {self.folder}: {done}/{len(runs)} run(s) complete{mark}>"

    @property
    def partial(self) -> bool:
        """Whether the folder was kept after an interruption (``partial.txt``)."""
        return (self.folder / _PARTIAL).is_file()

    @property
    def complete(self) -> bool:
        """Whether every run is complete (and the folder not partial)."""
        return not self.partial and all(r.status == "complete" for r in self.runs)

    @property
    def runs(self) -> list[Run]:
        """Every run, in the order of summary.csv."""
        if self._runs is None:
            path = self.folder / _SUMMARY
            rows = list(csv.DictReader(io.StringIO(self._summary_text(), newline="")))
            labels: set[str] = set()
            for number, row in enumerate(rows, 2):
                label = row.get("run")
                problem = _label_problem(label) or (
                    "is listed twice" if label in labels else None)
                if problem:
                    raise _damaged(path, f"row {number}: run {label!r} {problem}")
                labels.add(str(label))
            self._runs = [self._read_run(row) for row in rows]
        return self._runs

    def _summary_text(self) -> str:
        """summary.csv's text (checked: a regular file of at most CSV_LIMIT bytes, UTF-8,
        whose header has the columns ``run``, ``variant`` and ``status``)."""
        path = self.folder / _SUMMARY
        text = _read(path, lambda: read_text(path, CSV_LIMIT, _SUMMARY))
        try:
            header = next(csv.reader(io.StringIO(text, newline="")), [])
        except csv.Error as error:
            raise _damaged(path, f"not CSV ({error})") from None
        if header[:3] != ["run", "variant", "status"]:
            raise _damaged(path, "its header is not run, variant, status, ...; not a "
                           "summary.csv of agv-cosim")
        return text

    def _read_run(self, row: dict[str, str]) -> Run:
        label = row["run"]
        folder = self.folder / label
        if os.path.islink(folder):
            raise _damaged(folder, f"run {label!r} is a symbolic link, not the run's folder")
        path = folder / "run.json"
        try:
            raw = read_bytes(path, JSON_LIMIT)
        except FileNotFoundError:  # a run that never started has no run.json
            return Run(label=label, status=row.get("status") or "", folder=folder,
                       message=None if row.get("status") == "complete" else
                       row.get("status"), variant=row.get("variant") or None)
        except (OSError, UnreadableFile) as error:
            raise _unreadable(path, error) from None
        info = _record(path, raw)
        if info.get("label", label) != label:
            raise _damaged(path, f"is the record of run {info.get('label')!r}, not of "
                           f"{label!r} (summary.csv)")
        point = info.get("sweep_point") or {}
        rows = info.get("rows") or 0
        for key, value, kind in (("status", info.get("status", ""), str),
                                 ("error", info.get("error"), (str, type(None))),
                                 ("variant", info.get("variant"), (str, type(None))),
                                 ("metrics_error", info.get("metrics_error"),
                                  (str, type(None))),
                                 ("sweep_point", point, dict),
                                 ("interfaces", info.get("interfaces", {}), dict),
                                 ("integration", info.get("integration", {}), dict)):
            if not isinstance(value, kind):
                raise _damaged(path, f"{key}: {value!r} is not a "
                               f"{'table' if kind is dict else 'string'}")
        if isinstance(rows, bool) or not isinstance(rows, int) or rows < 0:
            raise _damaged(path, f"rows: {rows!r} is not a count of rows")
        return Run(label=label, status=info.get("status", row.get("status", "")),
                   folder=folder, message=info.get("error"), variant=info.get("variant"),
                   point=dict(point), rows=rows, metrics_error=info.get("metrics_error"),
                   interfaces=dict(info.get("interfaces", {})),
                   integration=dict(info.get("integration", {})))

    def run(self, label: str) -> Run:
        """The run labelled ``label`` (one of summary.csv's)."""
        if not isinstance(label, str):
            raise AgvCosimError(f"{self.folder}: run label {label!r} is not a string")
        for one in self.runs:
            if one.label == label:
                return one
        raise AgvCosimError(f"{self.folder}: no run '{label}' (runs: "
                            f"{', '.join(r.label for r in self.runs) or 'none'})")

    @property
    def summary(self) -> "pandas.DataFrame":
        """summary.csv as a DataFrame (its floats read back exactly): one row per run
        (``run``, ``variant``, ``status``, the sweep values, the metrics), plus
        ``message``: why a run is not complete (from its run.json; not a column of the
        file). ``attrs["units"]`` maps each column to its unit (None: none) and
        ``attrs["descriptions"]`` to what it is (a metric's definition: docs/metrics.md),
        as the report page shows them."""
        import pandas

        messages = {r.label: r.message for r in self.runs}
        path = self.folder / _SUMMARY
        text = self._summary_text()
        try:
            frame = pandas.read_csv(io.StringIO(text), keep_default_na=False,
                                    na_values=[""])
        except (ValueError, csv.Error) as error:  # pandas' ParserError is a ValueError
            raise _damaged(path, f"not CSV ({_first_line(error)})") from None
        for name in frame.columns[3:]:  # a column of numbers with "nan" or "inf" among them
            if pandas.api.types.is_string_dtype(frame[name]):
                try:
                    frame[name] = [float(value) for value in frame[name]]
                except (TypeError, ValueError):  # text (a string parameter swept)
                    pass
        frame["message"] = [messages.get(label) for label in frame["run"]]
        frame.attrs["units"], frame.attrs["descriptions"] = _summary_attrs(
            self.folder, [str(name) for name in frame.columns])
        return frame

    def timeseries(self, label: str) -> "pandas.DataFrame":
        """The run's timeseries.csv as a DataFrame indexed by ``time`` [s], one column
        per recorded variable (``component.variable``; the values bit-identical to the
        file's); ``attrs['units']`` maps each column (and ``time``) to its unit from the
        model descriptions (None: none declared)."""
        import pandas

        one = self.run(label)
        path = one.folder / "timeseries.csv"
        try:
            stream = open_regular(path)
        except FileNotFoundError:
            raise AgvCosimError(f"{path}: not found (run {label} is {one.status})") \
                from None
        except (OSError, UnreadableFile) as error:
            raise _unreadable(path, error) from None
        try:
            with stream:
                frame = pandas.read_csv(stream, index_col="time", encoding="utf-8")
        except (ValueError, csv.Error) as error:  # ParserError, no time column, not UTF-8
            raise _damaged(path, f"not a timeseries.csv of agv-cosim "
                           f"({_first_line(error)})") from None
        except MemoryError:
            raise AgvCosimError(f"{path}: too large to read whole (agv_cosim.timeseries."
                                "iter_timeseries reads it in pieces)", exit_code=1) from None
        frame.attrs["units"] = self._units(one, ["time", *frame.columns])
        return frame

    def _units(self, one: Run, columns: list[str]) -> dict[str, str | None]:
        path = one.folder / "run.json"
        try:
            info = _record(path, read_bytes(path, JSON_LIMIT))
        except OSError:
            info = {}
        except UnreadableFile as error:
            raise _unreadable(path, error) from None
        known = info.get("units")
        if not isinstance(known, dict):
            known = _units_from_models(info)
        return {name: _text_or_none(known.get(name)) for name in columns}

    def _repr_html_(self) -> str:
        table: str = self.summary._repr_html_()
        return f"<p>{_escape(repr(self))}</p>" + table


def _label_problem(label: object) -> str | None:
    """Why ``label`` cannot be a run's label (one path component), or None."""
    if not isinstance(label, str) or not label:
        return "is empty"
    if label in (".", "..") or "/" in label or "\0" in label or "\\" in label:
        return "is not a plain folder name (one path component)"
    return None


def _damaged(path: Path, problem: str) -> AgvCosimError:
    """The error of a damaged result folder: ``<path>: <problem>`` (exit code 2)."""
    return AgvCosimError(printable(f"{path}: {problem}"), exit_code=2)


def _unreadable(path: Path, error: BaseException) -> AgvCosimError:
    """The error of a file that cannot or must not be read (OSError, UnreadableFile)."""
    if isinstance(error, OSError):
        return _damaged(path, f"cannot read: {error.strerror or error}")
    return AgvCosimError(printable(str(error)), exit_code=2)


def _read(path: Path, read: Callable[[], _T]) -> _T:
    try:
        return read()
    except (OSError, UnreadableFile) as error:
        raise _unreadable(path, error) from None


def _record(path: Path, raw: bytes) -> dict[str, Any]:
    """The JSON object of a run.json (``raw``: its bytes)."""
    try:
        info = json.loads(raw.decode("utf-8"))
    except (ValueError, RecursionError) as error:
        raise _damaged(path, f"not JSON ({error})") from None
    if not isinstance(info, dict):
        raise _damaged(path, "not a JSON object")
    return info


def _first_line(error: BaseException) -> str:
    text = str(error).strip()
    return text.splitlines()[0] if text else type(error).__name__


def _text_or_none(value: Any) -> str | None:
    return value if isinstance(value, str) else None


def _escape(text: str) -> str:
    import html

    return html.escape(text)


def _units_from_models(info: dict[str, Any]) -> dict[str, str | None]:
    """Units of a run.json without ``units`` (written by an older agv-cosim): read from
    its FMUs when they are still there, unchanged (same SHA-256)."""
    from .system.model import read_model

    units: dict[str, str | None] = {"time": "s"}
    hashes, fmus = info.get("fmu_sha256"), info.get("fmus")
    if not isinstance(hashes, dict) or not isinstance(fmus, dict):
        return units
    for cname, path in fmus.items():
        if not isinstance(path, str):
            continue
        try:
            model = read_model(path)
        except (ModelError, OSError, ValueError, UnreadableFile):
            continue
        if model.sha256 != hashes.get(cname):
            continue
        for vname, variable in model.variables.items():
            units[f"{cname}.{vname}"] = variable.unit
    return units


#: What summary's columns other than the sweep values and the metrics are.
_COLUMNS = {"run": "the run's label: its folder's name",
            "variant": "the variant the run is of (empty: the base experiment)",
            "status": "complete, partial, failed, timed out, interrupted or not run",
            "message": "why the run is not complete (its run.json's error; empty when it "
                       "is); not a column of summary.csv"}


def _summary_attrs(folder: Path, columns: list[str]) -> tuple[dict[str, str | None],
                                                              dict[str, str]]:
    """Units and descriptions of summary's ``columns``: the report page's units (the FMUs'
    for swept parameters, :mod:`agv_cosim.report.metrics` and the recorded signals' for
    metrics) and the metrics' definitions."""
    from .report.metrics import METRICS
    from .report.page import collect_units, read_manifest, read_runs
    from .report.plots import SAMPLE_KEY

    runs = read_runs(folder)
    manifest, _ = read_manifest(folder, runs) if runs else ({}, "")
    known = collect_units(runs, manifest) if runs else {}
    units = {name: known.get(name) for name in columns}
    descriptions = {}
    for name in columns:
        if name in _COLUMNS:
            descriptions[name] = _COLUMNS[name]
        elif name in METRICS:
            descriptions[name] = f"{METRICS[name].definition} (empty when: " \
                                 f"{METRICS[name].empty})"
        elif name == SAMPLE_KEY:
            descriptions[name] = "the Monte Carlo sample's index"
        else:
            descriptions[name] = f"the value of {name} in the run (swept or sampled)"
    return units, descriptions


def open_results(folder: str | Path) -> Results:
    """The result folder ``folder`` (written by ``agv-cosim run`` or :func:`run`)."""
    return Results(folder)


def _set_value(value: Any) -> Any:
    """A Python value of ``sets`` as the typed value of an override (a bool, int,
    float or str, or a list of them)."""
    if isinstance(value, bool):
        return bool(value)
    if isinstance(value, float):
        return float(value)
    if isinstance(value, int):
        return int(value)
    if isinstance(value, str):
        return str(value)
    if isinstance(value, (list, tuple)):
        return [_set_value(v) for v in value]
    raise AgvCosimError(f"set: {value!r}: not a number, boolean, string or list")


def _set_items(sets: Mapping[str, Any] | Iterable[str]) -> "list[str | Override]":
    """``sets`` as the plan takes them: a mapping's values typed (:class:`Override`),
    text as it is (parsed by :func:`agv_cosim.plan.parse_set`)."""
    from .plan import Override

    if isinstance(sets, str):
        return [sets]
    if isinstance(sets, Mapping):
        return [Override(str(name), _set_value(value)) for name, value in sets.items()]
    return list(_strings(sets, "sets", "an override 'component.parameter=value'"))


def _strings(values: Any, option: str, what: str) -> list[str]:
    """``values`` (an iterable of strings) as a list; AgvCosimError naming ``option``
    for anything else."""
    if isinstance(values, (bytes, Mapping)) or not isinstance(values, Iterable):
        raise AgvCosimError(f"{option}: {values!r} is not a list of strings")
    items = list(values)
    for item in items:
        if not isinstance(item, str):
            raise AgvCosimError(f"{option}: {item!r} is not {what} (a string)")
    return items


def _path_option(value: Any, option: str, optional: bool = False) -> None:
    """AgvCosimError naming ``option`` unless ``value`` is a path (str or os.PathLike;
    None when ``optional``)."""
    if value is None and optional:
        return
    if isinstance(value, bool) or not isinstance(value, (str, os.PathLike)):
        raise AgvCosimError(f"{option}: {value!r} is not a path")



def _say(text: str) -> None:
    print(printable(text), file=sys.stderr)


def run(manifest: str | Path, *, out: str | Path | None = None,
        variants: Iterable[str] | None = None,
        sets: Mapping[str, Any] | Iterable[str] = (), jobs: int | None = None,
        quiet: bool = False, overwrite: bool = False, dask: str | None = None,
        timeout: float | None = None, init_check: bool = True,
        check: bool = False, check_step: bool = False) -> Results:
    """Run a manifest as ``agv-cosim run`` does and return its :class:`Results`.

    Parameters
    ----------
    manifest : path
        An experiment manifest (TOML) or an SSP package.
    out : path, optional
        The result folder (``--out``; default ``results/<manifest name>``).
    variants : names, optional
        Run only these variants (``--variant``; default all).
    sets : mapping or strings
        Parameter overrides in every run (``--set``): ``{"vehicle.wheelbase": 1.2}`` or
        ``["vehicle.wheelbase=1.2"]`` (the value as TOML text).
    jobs : int, optional
        Runs at once (``--jobs``; default one per core).
    quiet : bool
        No progress bar and no messages on stderr (``--quiet``; warnings are kept in
        ``Results.warnings`` either way).
    overwrite : bool
        Replace ``out`` even if it is not a result folder of agv-cosim (``--overwrite``).
    dask : str, optional
        The Dask scheduler to run on (``--dask tcp://HOST:PORT``).
    timeout : float, optional
        Wall-clock limit of each run [s] (``--timeout``).
    init_check : bool
        Instantiate and initialise each FMU once with each run's parameters before any
        run is written (``--no-init`` is ``init_check=False``; skipped with ``dask``).
    check : bool
        Raise :class:`~agv_cosim.errors.AgvCosimError` when a run is not complete (its
        message is the command's line about the first such run); by default such runs
        are in the results with their status and message.
    check_step : bool
        Run each complete run again at step/2 and step/4 and write the step check,
        ``step_check.json`` (``--check-step``; docs/metrics.md).

    Raises
    ------
    AgvCosimError
        For everything ``agv-cosim run`` reports as an error; ``str()`` is its line.
    KeyboardInterrupt, Interrupted
        When interrupted; once runs started it is a
        :class:`~agv_cosim.errors.RunsStopped`, whose ``.kept`` is the result folder
        kept marked partial (or None).
    """
    from .lifetime import (
        clean_stale_scratch,
        termination_signals,
        use_own_scratch_for_multiprocessing,
    )

    if jobs is not None and (isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1):
        raise AgvCosimError(f"jobs: must be an integer >= 1, not {jobs!r}")
    if timeout is not None and not (isinstance(timeout, (int, float))
                                    and math.isfinite(timeout) and timeout > 0):
        raise AgvCosimError(f"timeout: {timeout!r} must be a positive, finite number of "
                            "seconds")
    _path_option(manifest, "manifest")
    _path_option(out, "out", optional=True)
    overrides = _set_items(sets)
    chosen = [variants] if isinstance(variants, str) else (
        _strings(variants, "variants", "a variant name") if variants is not None else None)
    try:
        with termination_signals():
            use_own_scratch_for_multiprocessing()
            clean_stale_scratch()
            target, results, warnings = _run(manifest, out, chosen, overrides, jobs, quiet,
                                             overwrite, dask, timeout, init_check,
                                             check_step)
    except (ManifestError, OutputError, UnreadableFile, FolderLost, ReportError,
            ClusterError, OSError) as error:
        # ReportError: the results were written, their page was not; OSError: the
        # system refused (disk full, permissions, ...)
        lines = error_lines(error)
        kept = error.kept if isinstance(error, (ReportError, RunsStopped)) else None
        raise AgvCosimError(lines[0], lines, exit_code(error), kept=kept) from error
    bad = [r for r in results if r["status"] != "complete"]
    lines = [f"run {r['label']} {r['status']}: {r['error']}" for r in bad]
    lines += [f"run {r['label']}: metrics: {r['metrics_error']}"
              for r in results if r.get("metrics_error")]
    if not quiet:
        for line in lines:
            _say(f"agv-cosim: {line}")
    if check and lines:
        raise AgvCosimError(lines[0], lines, 1)
    return Results(target, warnings)


def _run(manifest: str | Path, out: str | Path | None, variants: list[str] | None,
         sets: "list[str | Override]", jobs: int | None, quiet: bool, overwrite: bool,
         dask: str | None,
         timeout: float | None, init_check: bool,
         check_step: bool = False) -> tuple[Path, list[Any], list[str]]:
    """``agv-cosim run``'s steps: prepare, the initialisation check, execute."""
    from .pipeline import INIT_TIMEOUT, execute, prepare
    from .ssp.importer import opened

    with opened(manifest) as source:
        loaded, planned, warnings = prepare(source, variants, sets, timeout=timeout)
        if not quiet:
            for warning in warnings:
                _say(f"agv-cosim: warning: {warning}")
        limit = max(timeout or loaded.timeout or 0.0, INIT_TIMEOUT) \
            if init_check and dask is None else None
        target, results = execute(loaded, planned, out, jobs, quiet, overwrite=overwrite,
                                  dask=dask, init_limit=limit, check_step=check_step)
    return target, list(results), warnings


def identify(data: str | Path, *, input: str, output: str, out: str | Path | None = None,
             time: str = "time", models: str | Iterable[str] = "a,b,c",
             cutoff: float = 30.0, order: int = 3,
             overwrite: bool = False) -> dict[str, Any]:
    """Identify the steering-actuator models from a measured record, as ``agv-cosim
    identify`` does (docs/identify.md).

    Returns a dict: ``"models"``, identified.json's content (``{model: {"parameters":
    {name: {"value", "stderr"[, "reason"]}}, "fit_percent"}}``); ``"parameters"``, a
    DataFrame with one row per model and parameter (``model``, ``parameter``, ``unit``,
    ``value``, ``stderr``, ``reason``); ``"responses"``, a DataFrame indexed by time
    (relative to the record's first sample) with the input, the measured output and
    each model's response; ``"settings"``, what the procedure used and found (sampling
    step, filter, initial values, dead-time estimate); ``"folder"``, the folder written
    (None without ``out``).

    Raises
    ------
    AgvCosimError
        (:class:`~agv_cosim.errors.IdentifyError`) for a record that cannot be
        identified from, one line naming the culprit; also for an output folder that is
        not ours.
    """
    import pandas

    from .identification import identify_file
    from .identification.numerics import UNITS

    chosen = models if isinstance(models, str) else tuple(models)
    try:
        found = identify_file(data, input, output, time=time, models=chosen,
                              cutoff=cutoff, order=order, out=out, overwrite=overwrite)
    except OutputError as error:
        raise AgvCosimError(str(error), exit_code=2) from error
    rows = [{"model": model, "parameter": name, "unit": UNITS.get(name),
             "value": entry["value"], "stderr": entry["stderr"],
             "reason": entry.get("reason")}
            for model, fit in found.result.items()
            for name, entry in fit["parameters"].items()]
    responses = pandas.DataFrame(found.responses).set_index("time")
    return {"models": found.result, "parameters": pandas.DataFrame(rows),
            "responses": responses, "settings": found.record["settings"],
            "folder": found.folder}


def tune(manifest: str | Path, *, out: str | Path, jobs: int | None = None,
         dask: str | None = None, overwrite: bool = False, quiet: bool = True,
         timeout: float | None = None) -> dict[str, Any]:
    """Tune the parameters of a manifest's ``[tune]`` table as ``agv-cosim tune`` does
    (docs/tune.md) and write the folder ``out``.

    Returns a dict: ``"best"`` (parameter -> tuned value), ``"best_value"`` and
    ``"start_value"`` (the objective, tuned and original; ``inf`` when infeasible),
    ``"record"`` (tune.json's content), ``"history"`` (a DataFrame, one row per trial:
    ``number``, ``generation``, the parameters, ``value``), ``"comparison"`` (a
    DataFrame, one row per run and ``which`` = original/tuned, with its status and
    metrics), ``"failed_runs"`` (the runs that failed during the search: their
    candidates were infeasible), ``"folder"``.

    Raises
    ------
    AgvCosimError
        For everything ``agv-cosim tune`` reports as an error (a bad manifest or
        ``[tune]``, an output folder that is not ours); ``str()`` is its line.
    """
    import pandas

    from .lifetime import (
        clean_stale_scratch,
        termination_signals,
        use_own_scratch_for_multiprocessing,
    )
    from .ssp.importer import opened
    from .tuning import tune_manifest

    if jobs is not None and (isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1):
        raise AgvCosimError(f"jobs: must be an integer >= 1, not {jobs!r}")
    _path_option(manifest, "manifest")
    _path_option(out, "out")
    try:
        with termination_signals():
            use_own_scratch_for_multiprocessing()
            clean_stale_scratch()
            with opened(manifest) as source:
                found = tune_manifest(source, out,
                                      workers=jobs, dask=dask, overwrite=overwrite,
                                      quiet=quiet, timeout=timeout)
    except (ManifestError, OutputError, UnreadableFile, FolderLost, ClusterError,
            OSError) as error:
        lines = error_lines(error)
        raise AgvCosimError(lines[0], lines, exit_code(error)) from error
    result = found.result
    history = pandas.DataFrame([{"number": t.number, "generation": t.generation,
                                 **t.parameters, "value": t.value}
                                for t in result.history])
    rows = [{"run": run, "which": which, "status": entry["status"], **entry["metrics"]}
            for run, pair in found.record["comparison"].items()
            for which, entry in pair.items()]
    return {"best": dict(result.best), "best_value": result.best_value,
            "start_value": result.start_value, "record": found.record,
            "history": history, "comparison": pandas.DataFrame(rows),
            "failed_runs": list(found.failures), "folder": found.folder}



def fit(manifest: str | Path, *, out: str | Path | None = None, variant: str | None = None,
        jobs: int | None = None, dask: str | None = None, overwrite: bool = False,
        max_evaluations: int | None = None) -> dict[str, Any]:
    """Fit the parameters of a manifest's ``[fit]`` table to its measured data, as
    ``agv-cosim fit`` does (docs/fit.md).

    Returns a dict: ``"fit"``, fit.json's content (``{"parameters": {name: {"value",
    "stderr"[, "reason"]}}, "correlation", "cost", "iterations", "evaluations", "runs",
    "converged", ...}``); ``"parameters"``, a DataFrame with one row per parameter
    (``parameter``, ``unit``, ``start``, ``min``, ``max``, ``value``, ``stderr``,
    ``reason``); ``"signals"``, a DataFrame indexed by the data's time with, per fitted
    signal, the measured, fitted and residual values (columns ``"<signal> measured"``,
    ``"<signal> fitted"``, ``"<signal> residual"``); ``"runs"``, the runs made;
    ``"folder"``, the folder written (None without ``out``).

    Raises
    ------
    AgvCosimError
        For everything ``agv-cosim fit`` reports as an error, ``str()`` its line: bad
        input (exit code 2), a run that failed (1), a fit that did not converge
        (:class:`~agv_cosim.errors.FitNotConverged`, 2; ``kept`` the folder written,
        marked, ``result`` the best point).
    """
    import pandas

    from .lifetime import (
        clean_stale_scratch,
        termination_signals,
        use_own_scratch_for_multiprocessing,
    )
    from .manifest_fit import fit_manifest

    if jobs is not None and (isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1):
        raise AgvCosimError(f"jobs: must be an integer >= 1, not {jobs!r}")
    _path_option(manifest, "manifest")
    _path_option(out, "out", optional=True)
    try:
        with termination_signals():
            use_own_scratch_for_multiprocessing()
            clean_stale_scratch()
            found = fit_manifest(manifest, out, variant=variant, jobs=jobs, dask=dask,
                                 overwrite=overwrite, max_evaluations=max_evaluations)
    except (ManifestError, OutputError, UnreadableFile, FolderLost, ClusterError,
            OSError) as error:
        lines = error_lines(error)
        raise AgvCosimError(lines[0], lines, exit_code(error)) from error
    result, setup = found.result, found.setup
    rows = [{"parameter": p.name, "unit": p.unit, "start": p.start,
             "min": setup.bounds[p.name][0], "max": setup.bounds[p.name][1],
             "value": result.values[p.name], "stderr": result.stderr[p.name],
             "reason": result.reasons.get(p.name)} for p in setup.parameters]
    columns: dict[str, Any] = {"time": setup.data.time}
    for signal, column in setup.signals.items():
        columns[f"{signal} measured"] = setup.data.columns[column]
        columns[f"{signal} fitted"] = result.fitted[signal]
        columns[f"{signal} residual"] = result.residuals[signal]
    return {"fit": result.as_json(), "parameters": pandas.DataFrame(rows),
            "signals": pandas.DataFrame(columns).set_index("time"), "runs": found.runs,
            "folder": found.folder}
