"""What ``agv-cosim fit`` shows (:mod:`.command`): the manifest fragment
of the fitted variant, the figure (measured and fitted signals overlaid, the residuals)
and the page (the run page's template and style)."""

from __future__ import annotations

import html
import math
import os
from importlib import resources
from pathlib import Path
from string import Template
from typing import TYPE_CHECKING, Any
from urllib.parse import quote

from ..files import open_output

if TYPE_CHECKING:
    from ..fitting import FitResult
    from .checks import FitSetup

__all__ = ["draw", "fragment", "render"]

FIGURE = "fit.png"


def _toml_string(text: str) -> str:
    return '"' + text.replace("\\", "\\\\").replace('"', '\\"') + '"'


def fragment(setup: FitSetup, result: FitResult, variant: str = "fitted") -> str:
    """``[variants.<variant>]``: each fitted component with the FMU it ran (relative to
    the manifest's folder) and the fitted values, to paste into a manifest."""
    manifest = setup.manifest
    data = manifest.fit.data if manifest.fit else "the data"
    state = "converged" if result.converged else f"NOT CONVERGED ({result.message})"
    out = [f"# The parameters fitted by agv-cosim fit to {data} (manifest {manifest.name}, "
           f"{state}).",
           "# Paste into a manifest in the same folder whose components have these names:",
           f"# `agv-cosim run M --variant {variant}` runs the fitted model (FMU paths are",
           "# relative to the manifest's folder; change them for another folder).", "",
           f"[variants.{variant}]",
           f"description = {_toml_string(f'fitted to {data} by agv-cosim fit')}"]
    by_component: dict[str, list[str]] = {}
    for p in setup.parameters:
        value = result.values[p.name]
        stderr = result.stderr.get(p.name)
        note = f"+- {stderr:.3g}" if stderr is not None else result.reasons.get(p.name, "")
        by_component.setdefault(p.component, []).append(
            f"{_toml_bare(p.parameter)} = {float(value)!r}  # {note}".rstrip(" #"))
    for component, lines in by_component.items():
        out.append(f"[variants.{variant}.components.{component}]")
        path = setup.job.plan.models[component].path
        relative = os.path.relpath(path, manifest.files_dir)
        out.append(f"fmu = {_toml_string(Path(relative).as_posix())}")
        out.append(f"[variants.{variant}.components.{component}.parameters]")
        out.extend(lines)
    return "\n".join(out) + "\n"


def _toml_bare(name: str) -> str:
    ok = name and all(c.isalnum() or c in "_-" for c in name)
    return name if ok else _toml_string(name)


def draw(path: Path, setup: FitSetup, result: FitResult, dpi: int = 110) -> None:
    """Per signal: the measured samples and the fitted signal at the data's stamps,
    and below the residuals (fitted - measured)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    signals = list(setup.signals)
    n = len(signals)
    figure = Figure(figsize=(9.0, 2.0 + 3.4 * n), layout="constrained")
    FigureCanvasAgg(figure)
    axes = figure.subplots(2 * n, 1, sharex=True,
                           gridspec_kw={"height_ratios": [3, 1.3] * n})
    t = setup.data.time
    for k, signal in enumerate(signals):
        top, bottom = axes[2 * k], axes[2 * k + 1]
        column = setup.signals[signal]
        unit = setup.job.plan.models[signal.partition(".")[0]].variables[
            signal.partition(".")[2]].unit
        suffix = f" [{unit}]" if unit else ""
        top.plot(t, setup.data.columns[column], ".", color="0.55", ms=2.5,
                 label=f"measured '{column}'")
        top.plot(t, result.fitted[signal], color="#d62728", lw=1.3,
                 label=f"fitted {signal} (rms residual {result.rms[signal]:.3g})")
        top.set_ylabel(f"{signal}{suffix}")
        top.legend(loc="best", fontsize=8)
        bottom.plot(t, result.residuals[signal], color="#1f77b4", lw=0.8)
        bottom.axhline(0.0, color="0.3", lw=0.6)
        bottom.set_ylabel(f"residual{suffix}")
        for ax in (top, bottom):
            ax.grid(True, lw=0.4, alpha=0.5)
    axes[-1].set_xlabel("time [s]")
    state = "" if result.converged else " (NOT CONVERGED: best point found)"
    axes[0].set_title(f"agv-cosim fit {setup.manifest.name}: measured and fitted "
                      f"signals, residuals{state}")
    with open_output(path) as stream:
        figure.savefig(stream, dpi=dpi, format="png", metadata={"Software": None})


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _num(value: float | None) -> str:
    if value is None or not math.isfinite(value):
        return "<td></td>"
    return (f'<td class=num data-v="{_e(repr(float(value)))}" title="{_e(repr(value))}">'
            f"{value:.6g}</td>")


def render(setup: FitSetup, result: FitResult, record: dict[str, Any]) -> str:
    """index.html of a fit folder."""
    manifest = setup.manifest
    title = f"fit {manifest.name}"
    body = [f"<h1>{_e(title)}</h1>",
            f'<p class="description">The parameters of manifest <code>{_e(manifest.name)}'
            f"</code>{' (variant ' + _e(setup.job.variant) + ')' if setup.job.variant else ''}"
            f" fitted so that its signals match <code>{_e(record['data'])}</code> "
            f"({record['samples']} samples): output-error least squares with the "
            "co-simulation as the model.</p>"]
    if not result.converged:
        body.append(f'<p class="warning"><b>Not converged</b>: {_e(result.message)}. The '
                    "best point found is shown and written, without standard errors.</p>")
    body.append("<h2 id=parameters>Fitted parameters</h2>"
                "<p class=hint>Standard errors from the Jacobian of the weighted residuals "
                "at the optimum (docs/fit.md).</p>"
                '<table class="sortable"><thead><tr><th>parameter</th><th>unit</th>'
                "<th>start</th><th>min</th><th>max</th><th>fitted</th>"
                "<th>standard error</th><th>note</th></tr></thead><tbody>")
    for p in setup.parameters:
        low, high = setup.bounds[p.name]
        body.append(f"<tr><td><code>{_e(p.name)}</code></td><td>{_e(p.unit or '')}</td>"
                    f"{_num(p.start)}{_num(low)}{_num(high)}{_num(result.values[p.name])}"
                    f"{_num(result.stderr.get(p.name))}"
                    f"<td>{_e(result.reasons.get(p.name, ''))}</td></tr>")
    body.append("</tbody></table>")
    body.append("<h2 id=signals>Signals</h2>"
                '<table class="sortable"><thead><tr><th>signal</th><th>column</th>'
                "<th>weight</th><th>rms residual</th></tr></thead><tbody>")
    for signal, column in setup.signals.items():
        body.append(f"<tr><td><code>{_e(signal)}</code></td><td><code>{_e(column)}</code>"
                    f"</td>{_num(result.weights[signal])}{_num(result.rms[signal])}</tr>")
    body.append("</tbody></table>")
    body.append(f"<p>Cost {result.cost:.6g}; {result.iterations} iteration(s), "
                f"{result.evaluations} evaluation(s), {record['runs']} run(s) "
                f"({_e(record['runner'])}); {_e(result.message)}.</p>")
    body.append(f'<h2>Figure</h2><figure id="fig-{FIGURE}"><a href="{quote(FIGURE)}">'
                f'<img src="{quote(FIGURE)}" alt="{FIGURE}" loading="eager"></a>'
                f"<figcaption><code>{FIGURE}</code> measured and fitted signals at the "
                "data's time stamps, the residuals (fitted - measured)</figcaption>"
                "</figure>")
    files = ["fit.json", "fit_variant.toml", "fit_run.json", "fitted/timeseries.csv",
             "fitted/run.json"]
    body.append("<h2 id=files>Files</h2><ul>"
                + "".join(f'<li><a href="{quote(n)}">{_e(n)}</a></li>' for n in files)
                + f"</ul><p>Data: <code>{_e(record['data_path'])}</code>, SHA-256 "
                f"<code>{_e(record['data_sha256'])}</code>.</p>")
    template = Template(resources.files("agv_cosim.report").joinpath("page_template.html")
                        .read_text(encoding="utf-8"))
    return template.substitute(title=_e(title), body="\n".join(body))
