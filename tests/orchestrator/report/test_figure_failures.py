"""Hostile round four, figures and the page: text from manifests and FMUs is drawn as
plain text (a ``$`` is never mathtext); a figure that fails leaves no image (never an
empty PNG shown as a figure), the page says which and why, and ``agv-cosim report``
fails (exit 1, one line); a page that cannot be written is not left behind and the
command fails (exit 1, one line); a manifest whose file name is not UTF-8 gets its
page."""

import errno
import os

import numpy as np
import pytest

from agv_cosim import cli
from agv_cosim.report import page as report_page
from agv_cosim.report import plots
from agv_cosim.report.plots import RunData, plot_runs

#: mathtext cannot parse this (an unclosed \frac): it failed every figure that drew it
FORMULA = r"$\frac{a}{$"
PNG = b"\x89PNG\r\n\x1a\n"
#: a sweep with a metric that differs between its runs: its page draws sweep_metrics.png
SWEEP = '[sweep]\n"gain.k" = [1.0, 2.0]\n[metrics]\nlateral_error = "int.y"\n'


def _lines(capsys):
    return capsys.readouterr().err.strip().splitlines()


def test_names_and_titles_with_dollars_are_drawn_as_written(tmp_path):
    """A variable named ``s.$\\frac{a}{$``, a run labelled ``r$1$`` and a title with a
    formula: the figure is drawn, each text as written (mathtext failed: ValueError and
    an empty signals.png)."""
    t = np.linspace(0.0, 1.0, 11)
    name = f"s.{FORMULA}"
    runs = [RunData("r$1$", t, {name: t})]
    spec = {"title": f"{FORMULA} cost", "signals": [name]}
    figure = plots.signals_figure(runs, spec)
    texts = [figure.get_suptitle(), figure.axes[0].get_ylabel(),
             figure.legends[0].get_texts()[0].get_text()]
    assert texts == [f"{FORMULA} cost", name, "r$1$"]
    [written] = plot_runs(runs, spec, tmp_path)
    assert written.read_bytes().startswith(PNG)


def test_a_figure_that_fails_to_draw_leaves_no_file(tmp_path, monkeypatch):
    """A figure whose drawing fails leaves no file at all (before: the file was opened
    first, and a failure left it empty)."""
    t = np.linspace(0.0, 1.0, 11)
    figure = plots.signals_figure([RunData("r", t, {"s.e": t})], {"signals": ["s.e"]})

    def fail(*args, **kwargs):
        raise ValueError("cannot draw")

    monkeypatch.setattr(figure, "savefig", fail)
    with pytest.raises(ValueError, match="cannot draw"):
        plots.save_figure(figure, tmp_path / "signals.png")
    assert not (tmp_path / "signals.png").exists()


@pytest.fixture
def sweep(chain, tmp_path):
    """A result folder of a sweep (its page draws sweep_metrics.png)."""
    manifest = chain(extra=SWEEP)
    out = tmp_path / "out"
    assert cli.main(["run", str(manifest), "--out", str(out), "--quiet"]) == 0
    assert (out / "sweep_metrics.png").is_file()
    return out


def test_a_run_with_a_formula_in_its_title_draws_every_figure(chain, tmp_path, capsys):
    """``[plots] title`` with a formula mathtext cannot parse: signals.png and the page's
    sweep_metrics.png are drawn (before: signals.png was 0 bytes and shown on the page,
    sweep_metrics.png missing, the page said nothing, exit 0)."""
    manifest = chain(extra=SWEEP + f'[plots]\nsignals = ["gain.y"]\ntitle = \'{FORMULA}\'\n')
    out = tmp_path / "out"
    assert cli.main(["run", str(manifest), "--out", str(out), "--quiet"]) == 0
    assert _lines(capsys) == []
    for name in ("signals.png", "sweep_metrics.png"):
        assert (out / name).read_bytes().startswith(PNG), name
    assert not (out / "plots_error.txt").exists()
    assert not (out / report_page.FIGURES_ERROR).exists()


def test_a_figure_that_fails_is_marked_on_the_page(sweep, capsys, monkeypatch):
    """``agv-cosim report`` whose sweep figure fails: the page is written without it and
    says which figure and why (figures_error.txt); no image is left; the command fails
    with one line (exit 1). A report that draws it again removes the note."""
    (sweep / "sweep_metrics.png").unlink()

    def fail(*args, **kwargs):
        raise RuntimeError("no ink")

    with monkeypatch.context() as patch:
        patch.setattr(plots, "sweep_metrics_figure", fail)
        assert cli.main(["report", str(sweep)]) == 1
    note = sweep / report_page.FIGURES_ERROR
    assert note.read_text() == "sweep_metrics.png: RuntimeError: no ink\n"
    assert _lines(capsys) == [
        f"agv-cosim: error: {sweep / 'index.html'}: written without 1 figure(s) that "
        f"could not be drawn ({report_page.FIGURES_ERROR}: sweep_metrics.png: "
        "RuntimeError: no ink)"]
    page = (sweep / "index.html").read_text()
    assert "sweep_metrics.png: RuntimeError: no ink" in page
    assert 'src="sweep_metrics.png"' not in page
    assert not (sweep / "sweep_metrics.png").exists()
    assert cli.main(["report", str(sweep)]) == 0
    assert not note.exists() and 'src="sweep_metrics.png"' in (sweep /
                                                              "index.html").read_text()


def test_an_empty_image_is_never_shown_as_a_figure(sweep):
    """A 0-byte PNG in the folder (a figure an older version failed to draw) is not
    shown on the page."""
    (sweep / "signals.png").write_bytes(b"")
    assert cli.main(["report", str(sweep)]) == 0
    assert "signals.png" not in (sweep / "index.html").read_text()


class _Full:
    """A file whose every write fails as a full disk does."""

    def __init__(self, stream):
        self.stream = stream

    def write(self, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stream.close()


def _full_disk_for_the_page(monkeypatch):
    real = report_page.create_file

    def create(path, binary=False):
        stream = real(path, binary)
        return _Full(stream) if os.path.basename(path) == "index.html" else stream

    monkeypatch.setattr(report_page, "create_file", create)


@pytest.mark.parametrize("command", ["report", "run"])
def test_a_page_that_cannot_be_written_fails_the_command(chain, tmp_path, capsys,
                                                         monkeypatch, command):
    """The disk fills as index.html is written: no page is left (before: an empty
    index.html), the command fails with one line (exit 1; before: run exited 0); run
    keeps its results."""
    manifest = chain(extra=SWEEP)
    out = tmp_path / "out"
    if command == "report":
        assert cli.main(["run", str(manifest), "--out", str(out), "--quiet"]) == 0
        capsys.readouterr()
    _full_disk_for_the_page(monkeypatch)
    argv = ["report", str(out)] if command == "report" else \
        ["run", str(manifest), "--out", str(out), "--quiet"]
    assert cli.main(argv) == 1
    lines = _lines(capsys)
    page = out / "index.html"
    assert len(lines) == 1 and lines[0].startswith(f"agv-cosim: error: {page}: ")
    assert "No space left on device" in lines[0]
    assert not page.exists()
    assert (out / "summary.csv").is_file()
    if command == "run":
        assert lines[0].endswith(f"; the results are in {out}")


def test_a_manifest_whose_name_is_not_utf8_gets_its_page(chain, tmp_path, capsys,
                                                        monkeypatch):
    """A manifest file named with a byte that is not UTF-8: the page is written, the
    name shown with the byte escaped (before: index.html of 0 bytes, exit 0)."""
    text = chain().read_text()
    monkeypatch.chdir(tmp_path)
    name = os.fsdecode(b"ch\xffain.toml")
    with open(name, "w") as stream:
        stream.write(text)
    out = tmp_path / "out"
    assert cli.main(["run", name, "--out", str(out), "--quiet"]) == 0
    assert _lines(capsys) == []
    page = (out / "index.html").read_text(encoding="utf-8")
    assert "ch\\xffain.toml" in page


def test_the_api_says_a_page_was_not_written(chain, tmp_path, monkeypatch):
    """agv_cosim.run whose page cannot be written raises AgvCosimError (exit code 1),
    ``kept`` naming the result folder, which holds the results."""
    import agv_cosim

    out = tmp_path / "out"
    _full_disk_for_the_page(monkeypatch)
    with pytest.raises(agv_cosim.AgvCosimError) as raised:
        agv_cosim.run(chain(extra=SWEEP), out=out, quiet=True)
    assert raised.value.exit_code == 1 and raised.value.kept == out
    assert str(raised.value).startswith(f"{out / 'index.html'}: not written (")
    assert (out / "summary.csv").is_file() and not (out / "index.html").exists()
