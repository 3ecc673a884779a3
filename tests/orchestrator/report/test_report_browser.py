"""The report page in a real browser: Chromium (Debian's ``chromium`` and
``chromium-driver``, installed by ``make test-deps``) driven by Selenium.

The page is opened from disk (file://) with every host name unresolvable, so anything it
fetched from the network would fail and show as a console error. Checked: no console
message of level SEVERE or WARNING, every image loaded (``complete`` and
``naturalWidth > 0``), a click on a header sorts the runs table; a full-page screenshot
is written (into ``$AGV_REPORT_SHOTS`` when set, to be looked at).
"""

import base64
import os
import shutil
from pathlib import Path

import pytest
from test_report import MC, SWEEP12

from agv_cosim import cli

pytestmark = pytest.mark.slow

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")


def _browser():
    try:
        from selenium import webdriver
        from selenium.webdriver.chrome.service import Service
    except ImportError:
        webdriver = None
    missing = [name for name, found in (("chromium", CHROMIUM), ("chromedriver", DRIVER),
                                        ("selenium", webdriver)) if not found]
    if missing:
        reason = f"missing {', '.join(missing)} (make test-deps; pip install -e .[test])"
        if os.environ.get("CI"):
            pytest.fail(reason + ": CI must run the browser test")
        pytest.skip(reason)
    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for argument in ("--headless=new", "--no-sandbox", "--disable-gpu",
                     "--disable-dev-shm-usage", "--window-size=1280,900",
                     "--host-resolver-rules=MAP * ~NOTFOUND", "--allow-file-access-from-files"):
        options.add_argument(argument)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(options=options, service=Service(executable_path=DRIVER))


def _screenshot(driver, path):
    """A PNG of the whole page (not only the window) at ``path``."""
    metrics = driver.execute_cdp_cmd("Page.getLayoutMetrics", {})
    size = metrics.get("cssContentSize") or metrics["contentSize"]
    shot = driver.execute_cdp_cmd("Page.captureScreenshot", {
        "format": "png", "captureBeyondViewport": True,
        "clip": {"x": 0, "y": 0, "width": size["width"], "height": size["height"],
                 "scale": 1}})
    Path(path).write_bytes(base64.b64decode(shot["data"]))
    return path


def _check_page(driver, page, shot):
    driver.get(page.as_uri())
    state = driver.execute_script("return document.readyState")
    assert state == "complete"
    images = driver.execute_script(
        "return Array.from(document.images).map(function (i) {"
        " return [i.getAttribute('src'), i.complete, i.naturalWidth]; });")
    assert images, "the page shows no figure"
    for src, complete, width in images:
        assert complete and width > 0, f"image {src} did not load"
    logs = driver.get_log("browser")
    problems = [entry for entry in logs if entry["level"] in ("SEVERE", "WARNING")]
    assert problems == [], problems
    _screenshot(driver, shot)
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    return images


def _shots_dir(tmp_path):
    folder = os.environ.get("AGV_REPORT_SHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        return Path(folder)
    return tmp_path


def test_sweep_report_in_chromium(chain, tmp_path):
    path = chain(extra=SWEEP12)
    out = tmp_path / "sweep"
    assert cli.main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    driver = _browser()
    try:
        images = _check_page(driver, out / "index.html",
                             _shots_dir(tmp_path) / "report_sweep_test.png")
        assert [src for src, _, _ in images] == ["signals.png", "sweep_metrics.png"]
        # sorting: a click on lateral_error_max orders the runs by it (twice: descending)
        column = driver.execute_script(
            "var h = document.querySelector('table.runs thead tr').cells;"
            "for (var i = 0; i < h.length; i++) {"
            " if (h[i].textContent.indexOf('lateral_error_max') === 0) return i; }"
            "return -1;")
        assert column > 0
        read = ("return Array.from(document.querySelectorAll('table.runs tbody tr'))"
                f".map(function (r) {{ return parseFloat(r.cells[{column}].dataset.v); }});")
        header = driver.find_elements("css selector", "table.runs thead th")[column]
        header.click()
        ascending = driver.execute_script(read)
        assert ascending == sorted(ascending) and len(ascending) == 12
        header.click()
        assert driver.execute_script(read) == sorted(ascending, reverse=True)
        assert [e for e in driver.get_log("browser") if e["level"] == "SEVERE"] == []
        _check_fits(driver)
    finally:
        driver.quit()


def _check_fits(driver):
    """At 1280 px: the page does not scroll sideways, the runs table fits its box (no
    hidden column), its key metrics are there, every metric header links to a definition
    on the page, and a run that never settled says so."""
    assert driver.execute_script("return window.innerWidth") <= 1280
    page = driver.execute_script("return [document.documentElement.scrollWidth,"
                                 " document.documentElement.clientWidth];")
    assert page[0] <= page[1], page
    box = driver.execute_script(
        "var t = document.querySelector('table.runs'), b = t.parentElement;"
        "return [b.scrollWidth, b.clientWidth, t.getBoundingClientRect().right,"
        " document.documentElement.clientWidth];")
    assert box[0] <= box[1] and box[2] <= box[3], box
    heads = driver.execute_script(
        "return Array.from(document.querySelectorAll('table.runs thead th.metric'))"
        ".map(function (h) { var a = h.querySelector('a.def');"
        " return [h.textContent, a ? a.getAttribute('href') : null,"
        " a ? document.getElementById(a.getAttribute('href').slice(1)) !== null : false]; });")
    assert heads and all(href and found for _, href, found in heads), heads
    names = [text.split(" ")[0] for text, _, _ in heads]
    assert names[:3] == ["lateral_error_max", "lateral_error_rms",
                         "lateral_error_settling_time"], names
    cells = driver.execute_script(
        "return Array.from(document.querySelectorAll('table.runs td.empty'))"
        ".map(function (c) { return c.textContent; });")
    assert "did not settle" in cells


def test_montecarlo_report_in_chromium(chain, tmp_path):
    path = chain(extra=MC)
    out = tmp_path / "mc"
    assert cli.main(["run", str(path), "--out", str(out), "--quiet"]) == 0
    driver = _browser()
    try:
        images = _check_page(driver, out / "index.html",
                             _shots_dir(tmp_path) / "report_montecarlo_test.png")
        assert [src for src, _, _ in images] == ["signals.png", "montecarlo.png",
                                                "montecarlo_scatter.png"]
        _check_fits(driver)
    finally:
        driver.quit()
