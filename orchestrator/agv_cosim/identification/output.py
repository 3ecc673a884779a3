"""What ``agv-cosim identify`` writes: ``identified.json``, the figure, the manifest
fragment ``identified_variants.toml``, ``identify_run.json`` (the settings and what the
procedure found) and ``index.html``; assembled in a temporary folder and renamed into
place (:class:`agv_cosim.files.AtomicDir`: only a folder of ours is replaced)."""

from __future__ import annotations

import html
import math
from importlib import resources
from pathlib import Path
from string import Template
from typing import Any
from urllib.parse import quote

import numpy as np

from ..files import AtomicDir, json_text, open_output, write_json, write_text
from .numerics import FMUS, UNITS, ModelFit, Prepared

RESULT = "identified.json"
FIGURE = "identify.png"
FRAGMENT = "identified_variants.toml"
RECORD = "identify_run.json"
PAGE = "index.html"
COLOURS = {"a": "#d62728", "b": "#1f77b4", "c": "#2ca02c"}


def result_json(fits: dict[str, ModelFit]) -> dict[str, Any]:
    """identified.json's content: ``{model: {"parameters": {...}, "fit_percent": f}}``."""
    return {model: fit.as_json() for model, fit in fits.items()}


def _toml_float(value: float) -> str:
    return repr(float(value))


def fragment(fits: dict[str, ModelFit], source: str, component: str = "act",
             fmus: str = "../fmus") -> str:
    """The manifest fragment: one variant per model with the identified parameters."""
    out = [f"# Variants with the actuator parameters identified from {source} by",
           "# agv-cosim identify: paste into a manifest whose steering actuator is the",
           f"# component '{component}' (FMU paths relative to the manifest, as in",
           "# experiments/: change them to where your FMUs are).", ""]
    for model, fit in fits.items():
        out.append(f"[variants.{model}]")
        out.append(f'description = "Model {model} identified from {source} '
                   f'(fit {fit.fit_percent:.2f} %)"')
        out.append(f"[variants.{model}.components.{component}]")
        out.append(f'fmu = "{fmus}/{FMUS[model]}.fmu"')
        values, missing = [], []
        for name, entry in fit.parameters.items():
            if entry["value"] is None:
                missing.append(name)
            elif model == "a" and name == "tau" and entry["value"] <= 0.0:
                missing.append(name)  # model a needs tau > 0
            else:
                values.append(f"{name} = {_toml_float(entry['value'])}")
        if missing:
            out.append(f"# not identified (the FMU's default is used): {', '.join(missing)}")
        out.append("parameters = { " + ", ".join(values) + " }")
        out.append("")
    return "\n".join(out)


def draw(path: Path, prep: Prepared, fits: dict[str, ModelFit], labels: tuple[str, str, str],
         dpi: int = 110) -> None:
    """Measured output against each model's response, and the residuals."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    time_name, input_name, output_name = labels
    t = prep.t
    measured = prep.y + prep.y0
    figure = Figure(figsize=(9.0, 7.5), layout="constrained")
    FigureCanvasAgg(figure)
    top, middle, bottom = figure.subplots(3, 1, sharex=True,
                                          gridspec_kw={"height_ratios": [3, 2, 1.2]})
    top.plot(t, measured, color="0.55", lw=0.8, label=f"measured {output_name}")
    for model, fit in fits.items():
        top.plot(t, fit.response, color=COLOURS[model], lw=1.2, ls="--",
                 label=f"model {model} (fit {fit.fit_percent:.2f} %)")
        middle.plot(t, measured - fit.response, color=COLOURS[model], lw=0.8,
                    label=f"model {model}")
    top.set_ylabel(f"{output_name} [rad]")
    top.legend(loc="best", fontsize=8)
    top.set_title("agv-cosim identify: measured output and each model's response")
    middle.axhline(0.0, color="0.3", lw=0.6)
    middle.set_ylabel("residual [rad]")
    middle.legend(loc="best", fontsize=8)
    bottom.plot(t, prep.u + prep.u0, color="k", lw=0.9)
    bottom.set_ylabel(f"{input_name} [V]")
    bottom.set_xlabel(f"{time_name} - {time_name}[0] [s]")
    for axes in (top, middle, bottom):
        axes.grid(True, lw=0.4, alpha=0.5)
    with open_output(path) as stream:
        figure.savefig(stream, dpi=dpi, format="png", metadata={"Software": None})


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _number(value: float | None) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return ""
    return f"{value:.6g}"


def _num_cell(value: float | None) -> str:
    """A table cell of a number (sortable by value; exact value in its title)."""
    if value is None or not math.isfinite(value):
        return "<td></td>"
    return (f'<td class=num data-v="{_e(repr(float(value)))}" title="{_e(repr(value))}">'
            f"{_number(value)}</td>")


def render(record: dict[str, Any], result: dict[str, Any]) -> str:
    """The page's HTML (the run page's template and style)."""
    title = f"identify {record['data']}"
    body = [f"<h1>{_e(title)}</h1>",
            '<p class="description">Seed 000\'s identification procedure (eq 4 pre-filter, '
            "dead time, initial values removed, output-error fit) of the steering-actuator "
            f"models on <code>{_e(record['data'])}</code>: input "
            f"<code>{_e(record['input'])}</code> [V], output "
            f"<code>{_e(record['output'])}</code> [rad], time "
            f"<code>{_e(record['time'])}</code> [s].</p>"]
    s = record["settings"]
    body.append("<h2>Procedure</h2><ul>"
                f"<li>{s['samples']} samples every {_number(s['step'])} s</li>"
                f"<li>pre-filter: {_e(s['filter'])}, order {s['order']}, cut-off "
                f"{_number(s['cutoff_hz'])} Hz (applied to the residual)</li>"
                f"<li>initial values removed: input {_number(s['input_initial'])} V, output "
                f"{_number(s['output_initial'])} rad (mean before the input first changes, "
                f"at {_number(s['first_change_time'])} s)</li>"
                f"<li>dead time, first estimate (model a on whole steps): "
                f"{_number(s['dead_time_estimate'])} s</li></ul>")
    body.append("<h2 id=parameters>Identified parameters</h2>"
                "<p class=hint>Standard errors: sqrt(diag(sigma<sup>2</sup> (J<sup>T</sup>J)"
                "<sup>-1</sup>)); fit = 100 (1 - ||y - y_hat|| / ||y - mean(y)||) on the "
                "unfiltered output.</p>"
                '<table class="sortable"><thead><tr><th>model</th><th>FMU</th>'
                "<th>parameter</th><th>unit</th><th>value</th><th>standard error</th>"
                "<th>note</th><th>fit [%]</th></tr></thead><tbody>")
    for model, entry in result.items():
        for name, p in entry["parameters"].items():
            body.append(f"<tr><td>{_e(model)}</td><td>{_e(FMUS[model])}</td>"
                        f"<td><code>{_e(name)}</code></td><td>{_e(UNITS.get(name, ''))}</td>"
                        f"{_num_cell(p['value'])}{_num_cell(p['stderr'])}"
                        f"<td>{_e(p.get('reason', ''))}</td>"
                        f"{_num_cell(entry['fit_percent'])}</tr>")
    body.append("</tbody></table>")
    body.append(f'<h2>Figure</h2><figure id="fig-{FIGURE}"><a href="{quote(FIGURE)}">'
                f'<img src="{quote(FIGURE)}" alt="{FIGURE}" loading="eager"></a>'
                f"<figcaption><code>{FIGURE}</code> measured output against each model's "
                "response, the residuals and the input</figcaption></figure>")
    body.append("<h2 id=files>Files</h2><ul>"
                + "".join(f'<li><a href="{quote(n)}">{_e(n)}</a></li>'
                          for n in (RESULT, FRAGMENT, RECORD))
                + f"</ul><p>Data: <code>{_e(record['data_path'])}</code>, SHA-256 "
                f"<code>{_e(record['data_sha256'])}</code>.</p>")
    template = Template(resources.files("agv_cosim.report").joinpath("page_template.html")
                        .read_text(encoding="utf-8"))
    return template.substitute(title=_e(title), body="\n".join(body))


def write_folder(folder: AtomicDir, prep: Prepared, fits: dict[str, ModelFit],
                 record: dict[str, Any], labels: tuple[str, str, str]) -> Path:
    """Write the files into ``folder`` (an AtomicDir, made before the fit so that a
    folder we must not replace is refused at once) and rename it into place."""
    result = result_json(fits)
    assert folder.path is not None
    path = folder.path
    write_json(path / RESULT, result)
    write_json(path / RECORD, record)
    write_text(path / FRAGMENT, fragment(fits, Path(record["data"]).name))
    draw(path / FIGURE, prep, fits, labels)
    write_text(path / PAGE, render(record, result))
    return folder.commit()


def responses_table(prep: Prepared, fits: dict[str, ModelFit]) -> dict[str, np.ndarray]:
    """Columns of the responses: time, input, measured output, each model's response."""
    columns = {"time": prep.t, "input": prep.u + prep.u0, "measured": prep.y + prep.y0}
    columns.update({model: fit.response for model, fit in fits.items()})
    return columns


__all__ = ["FIGURE", "FRAGMENT", "PAGE", "RECORD", "RESULT", "draw", "fragment", "json_text",
           "render", "responses_table", "result_json", "write_folder"]
