"""The one manifest-rewriting helper of the test suite.

Tests that run a shipped experiment (``experiments/*.toml``) copy it into a temp folder
with its FMU paths, ``"../fmus/<Model>.fmu"``, pointed at the FMUs built for this test
session, and sometimes shorten it (a smaller sweep, an earlier stop). ``localise`` does
that in one place, checking every edit so that a change of the shipped manifest makes
the test fail loudly instead of silently running something else.
"""

import json
import re
from pathlib import Path

#: an FMU reference as the shipped manifests write it: ``"../fmus/AgvVehicle.fmu"``
FMU_REF = re.compile(r'"\.\./fmus/(\w+)\.fmu"')


def fmus_by_model(fmus):
    """Model name (the FMU's file stem, e.g. ``AgvVehicle``) -> FMU path, from a mapping
    of any keys to FMU paths (e.g. the ``component_fmus`` fixture: script stem -> path)."""
    return {Path(path).stem: Path(path) for path in fmus.values()}


def localise_text(text, fmus, replace=(), resub=()):
    """``text`` of a manifest with its ``"../fmus/<Model>.fmu"`` references pointed at
    ``fmus`` (any mapping whose values are FMU paths, looked up by file stem).

    ``replace``: (old, new) exact substitutions, each of which must occur exactly once.
    ``resub``: (pattern, replacement) regular expressions (multi-line mode), applied to
    every match, none required (for keys that a manifest may or may not have).
    """
    by_model = fmus_by_model(fmus)

    def point(match):
        model = match.group(1)
        assert model in by_model, f"no FMU built for {model} (have: {sorted(by_model)})"
        return json.dumps(by_model[model].as_posix())

    text = FMU_REF.sub(point, text)
    for old, new in replace:
        assert text.count(old) == 1, f"expected {old!r} once in the manifest"
        text = text.replace(old, new)
    for pattern, new in resub:
        text = re.sub(pattern, new, text, flags=re.M)
    return text


def localise(source, folder, fmus, replace=(), resub=(), name=None):
    """Copy the manifest file ``source`` into ``folder`` (as ``name``, default its own
    file name) through :func:`localise_text`; returns the new path."""
    source = Path(source)
    text = localise_text(source.read_text(encoding="utf-8"), fmus, replace, resub)
    path = Path(folder) / (name or source.name)
    path.write_text(text, encoding="utf-8")
    return path


def assert_complete(results, count, metrics=True):
    """Every one of ``count`` run results (``run_manifest``'s list) is ``complete`` and,
    with ``metrics``, has its metrics (none missing, no ``metrics_error``). A failure
    names each run that is not, with its status, rows, error and metrics error, so that
    an empty metrics table shows its reason instead of a KeyError later."""
    def wrong(result):
        if result.get("status") != "complete":
            return True
        return metrics and (result.get("metrics_error") is not None
                            or not result.get("metrics"))

    bad = [f"{r.get('label')}: status {r.get('status')!r}, {r.get('rows')} rows, "
           f"error {r.get('error')!r}, metrics_error {r.get('metrics_error')!r}, "
           f"metrics {sorted(r.get('metrics') or {})}" for r in results if wrong(r)]
    assert len(results) == count and not bad, (
        f"{len(results)} run(s), {count} expected; not complete with metrics: "
        + ("; ".join(bad) or "none"))
