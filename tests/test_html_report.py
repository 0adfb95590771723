"""The HTML report (`jaxba.html_report`) of the adjusted synthetic block: its structure parsed
with html.parser (every section, σ̂0 as the result has it, every figure embedded as PNG, no
script and no external address), and the page rendered by a headless Chromium where one is
installed (a non-blank screenshot of the window's size, the same σ̂0 in the rendered DOM, no
console errors)."""

import base64
import html.parser
import math
import re
import shutil
import subprocess

import numpy as np
import pytest
import scipy.stats

import jaxba
from jaxba._report._html import MAX_POINT_ROWS

pytest.importorskip("matplotlib").use("Agg")

SECTIONS = ["summary", "cameras", "images", "points", "groups", "residuals", "figures"]
PNG = b"\x89PNG\r\n\x1a\n"
WINDOW = (1200, 1600)  # the screenshot's size, pixels
CHROMIUM_SECONDS = 120


class _Page(html.parser.HTMLParser):
    """Tags, attributes and the text of elements with an id."""

    def __init__(self):
        super().__init__()
        self.tags, self.attributes, self.text, self._open = [], [], {}, []

    def handle_starttag(self, tag, attrs):
        self.tags.append(tag)
        self.attributes += [(tag, name, value) for name, value in attrs]
        element_id = dict(attrs).get("id")
        self._open.append(element_id)
        if element_id:
            self.text[element_id] = ""

    def handle_endtag(self, tag):
        if self._open:
            self._open.pop()

    def handle_data(self, data):
        for element_id in self._open:
            if element_id:
                self.text[element_id] += data


@pytest.fixture(scope="module")
def report(synthetic_block):
    _, project, result = synthetic_block
    text = jaxba.html_report(project, result)
    page = _Page()
    page.feed(text)
    return project, result, text, page


def test_sections_and_sigma0(report):
    project, result, text, page = report
    assert text.startswith("<!DOCTYPE html>")
    assert [i for i in page.text if i in SECTIONS] == SECTIONS
    sigma0 = math.sqrt(result.precision.sigma0_squared)
    assert float(page.text["sigma0"]) == pytest.approx(sigma0, rel=1e-5)
    assert page.text["sigma0"] == f"{sigma0:.6g}"
    rows = page.tags.count("tr")
    n_points = min(len(project.point_ids), MAX_POINT_ROWS)
    assert rows > len(project.image_ids) + n_points  # images and points tables in full
    for image_id in project.image_ids:
        assert image_id in page.text["images"]
    # c written to the second significant digit of its σ
    c = np.asarray(result.parameters.cameras["smac"])[0, 2]
    sigma = np.asarray(result.precision.std.cameras["smac"])[0, 2]
    digits = 1 - math.floor(math.log10(sigma))
    assert f"<td>{c:.{digits}f}</td><td>{sigma:.2g}</td><td>free</td>" in text


def test_summary_shows_the_chi_square_test_the_datum_and_the_iterations(report):
    """The χ² test of σ̂0 with its bounds computed here (a priori σ0 1), the lab's datum as
    the project defines it, and the accepted iterations."""
    _, result, _, page = report
    r = result.precision.redundancy
    low, high = scipy.stats.chi2.ppf([0.025, 0.975], r)
    statistic = r * result.precision.sigma0_squared
    test = page.text["variance-test"]
    assert f"r sigma0^2/prior^2 = {statistic:.1f} in [{low:.1f}, {high:.1f}]" in test
    assert ("passed" if low <= statistic <= high else "FAILED") in test
    assert page.text["datum"] == (
        "control: 3 control points (6 fixed, 0 weighted coordinates), 4 distances")
    assert int(page.text["iterations"]) == len(result.iterations) - 1 > 0


def test_offline_and_every_figure_embedded(report):
    project, result, _, page = report
    assert "script" not in page.tags and "link" not in page.tags
    links = [(tag, name, value) for tag, name, value in page.attributes
             if name in ("src", "href", "action", "poster", "srcset")]
    assert all(value.startswith(("#", "data:image/png;base64,")) for _, _, value in links)
    images = [value for tag, name, value in page.attributes if tag == "img" and name == "src"]
    names = [figure.name for figure in jaxba.figure_set(project, result)]
    assert len(images) == len(names)
    for image in images:
        assert base64.b64decode(image.split(",", 1)[1])[:8] == PNG
    figure_ids = [value for _, name, value in page.attributes
                  if name == "id" and value.startswith("figure-")]
    assert figure_ids == [f"figure-{name}" for name in names]


def test_points_table_capped(synthetic_block, monkeypatch):
    _, project, result = synthetic_block
    monkeypatch.setattr("jaxba._report._html.MAX_POINT_ROWS", 10)
    images = {figure.name: PNG for figure in jaxba.figure_set(project, result)}
    page = _Page()
    page.feed(jaxba.html_report(project, result, figures=images))
    assert f"The first 10 of {len(project.point_ids)} points" in page.text["points"]
    assert page.text["points"].count("σ X") == 1


@pytest.mark.skipif(shutil.which("chromium") is None, reason="chromium is not installed")
def test_chromium_renders_the_page(report, tmp_path):
    from matplotlib.image import imread

    _, result, text, _ = report
    page = tmp_path / "report.html"
    page.write_text(text, encoding="utf-8")
    common = ["chromium", "--headless", "--no-sandbox", "--disable-gpu", "--no-first-run",
              f"--user-data-dir={tmp_path / 'profile'}", "--enable-logging=stderr", "--v=0",
              f"--window-size={WINDOW[0]},{WINDOW[1]}", "--virtual-time-budget=5000"]
    shot = tmp_path / "shot.png"
    run = subprocess.run([*common, f"--screenshot={shot}", page.as_uri()], capture_output=True,
                         text=True, timeout=CHROMIUM_SECONDS)
    assert run.returncode == 0, run.stderr
    pixels = imread(shot)
    assert pixels.shape[:2] == (WINDOW[1], WINDOW[0])
    assert np.ptp(pixels[..., :3]) > 0.5 and np.std(pixels[..., :3]) > 0.05  # not blank
    dom = subprocess.run([*common, "--dump-dom", page.as_uri()], capture_output=True, text=True,
                         timeout=CHROMIUM_SECONDS)
    assert dom.returncode == 0, dom.stderr
    sigma0 = re.search(r'<span id="sigma0">([^<]*)</span>', dom.stdout)
    assert sigma0 and float(sigma0.group(1)) == pytest.approx(
        math.sqrt(result.precision.sigma0_squared), rel=1e-5)
    assert dom.stdout.count("<img ") == text.count("<img ")
    for log in (run.stderr, dom.stderr):
        assert "CONSOLE" not in log and "Failed to load resource" not in log
