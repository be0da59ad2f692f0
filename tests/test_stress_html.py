"""stress.html: the status matrix is colour-coded with "n/a" where a case does not apply, no word
breaks inside, and the rows' notes column stays on screen (headless Chromium)."""
from __future__ import annotations

import html.parser
import shutil

import pandas as pd
import pytest

from iblbench.reports.report import stress_html, unbroken_words

FIGURES = [f"figure_{i:02d}" for i in range(24)]          # enough columns to scroll sideways
NOTE = ("fixed by 289bb0f: the reference integrated the m = 0 step with 2×2 cells (2e-3 off; now "
        "exact) and a view-89.94deg-specular-m2-R2 variant with shading-normals-facing-away")


def _row(case, estimator, status, failures="", notes=""):
    return {"case": case, "estimator": estimator,
            "variants": "view-89.9deg, view-89.94deg-specular-m2-R2, shading-normals-facing-away",
            "status": status, **{name: 1234.5678 for name in FIGURES},
            "failures": failures, "notes": notes}


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    """A stress page of three cases: "everyone" applies to both estimators (uniform fails it),
    "temporal-only" only to smc."""
    table = pd.DataFrame([
        _row("everyone", "uniform", "FAIL", failures="biased: |z| = 5.10, p = 3.4e-07", notes=NOTE),
        _row("everyone", "smc", "pass", notes=NOTE),
        _row("temporal-only", "smc", "xfail", notes="known failure: filter lag ×6.6"),
    ])
    context = {"title": "iblbench stress", "verdict": "stress: FAILED", "failed": True,
               "device": "a device", "scale": "spp 8", "seconds": "1", "alpha_z": 0.001,
               "alpha_chi2": 0.01, "alpha_z_case": "1e-4", "alpha_chi2_case": "1e-3",
               "columns": [{"text": "One row per (case, estimator)."}],
               "design": [{"bullets": ["a one-sided test", "a two-sided test"]}]}
    cases = [{"name": "everyone", "guards": NOTE, "variants": "R=8", "z_pixels": "all",
              "notes": NOTE},
             {"name": "temporal-only", "guards": "recovery after a drop-out", "variants": "R=8",
              "z_pixels": "all", "notes": ""}]
    path = tmp_path_factory.mktemp("stress") / "stress.html"
    path.write_text(stress_html(table, cases, context), encoding="utf-8")
    return path


class _Matrix(html.parser.HTMLParser):
    """(text, class) of each cell of the first table."""

    def __init__(self):
        super().__init__()
        self.cells, self._cell, self._tables = [], None, 0

    def handle_starttag(self, tag, attrs):
        self._tables += tag == "table"
        if tag == "td" and self._tables == 1:
            self._cell = ["", dict(attrs).get("class", "")]

    def handle_endtag(self, tag):
        if tag == "td" and self._cell is not None:
            self.cells.append((self._cell[0].strip(), self._cell[1]))
            self._cell = None

    def handle_data(self, data):
        if self._cell is not None:
            self._cell[0] += data


def test_the_matrix_marks_each_status_and_n_a_where_a_case_does_not_apply(page):
    parser = _Matrix()
    parser.feed(page.read_text(encoding="utf-8"))
    # Columns uniform, smc; rows everyone, temporal-only.
    everyone, fail, passed, temporal, na, xfail = parser.cells
    assert (everyone[0], temporal[0]) == ("everyone", "temporal-only")
    assert fail == ("FAIL", "status s-fail") and passed == ("pass", "status s-pass")
    assert na == ("n/a", "status s-na") and xfail == ("xfail", "status s-xfail")


def test_words_with_hyphens_or_slashes_are_kept_whole_and_escaped():
    assert str(unbroken_words("a view-89.9deg <b> & x/y's")) == (
        'a <span class="nowrap">view-89.9deg</span> &lt;b&gt; &amp; '
        '<span class="nowrap">x/y&#39;s</span>')


CHROMIUM = shutil.which("chromium")

# Every word of every text node inside #stress: the distinct line tops of its client rects
# (one for a word drawn on one line, two or more for a word broken inside).
_BROKEN_WORDS = """() => {
  const broken = [];
  const walker = document.createTreeWalker(document.getElementById('stress'), NodeFilter.SHOW_TEXT);
  for (let node = walker.nextNode(); node; node = walker.nextNode()) {
    for (const match of node.data.matchAll(/\\S+/g)) {
      const range = document.createRange();
      range.setStart(node, match.index);
      range.setEnd(node, match.index + match[0].length);
      const tops = new Set(Array.from(range.getClientRects()).map(r => Math.round(r.top)));
      if (tops.size > 1) broken.push(match[0]);
    }
  }
  return broken;
}"""


@pytest.mark.skipif(CHROMIUM is None, reason="no Chromium installed (Debian package 'chromium')")
@pytest.mark.parametrize("width", [1280, 820])
def test_in_chromium_colours_differ_no_word_breaks_and_the_notes_stay_on_screen(page, width):
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as playwright:
        browser = playwright.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        try:
            tab = browser.new_page(viewport={"width": width, "height": 800})
            tab.goto(page.resolve().as_uri())
            tab.wait_for_load_state("load")
            colour = "s => getComputedStyle(document.querySelector(s)).backgroundColor"
            fail, passed, na = (tab.evaluate(colour, f"table.matrix td.s-{s}")
                                for s in ("fail", "pass", "na"))
            na_text = tab.inner_text("table.matrix tbody tr:nth-child(2) td:nth-child(2)")
            broken = tab.evaluate(_BROKEN_WORDS)
            scroller = "document.querySelector('table.rows').parentElement"
            overflow = tab.evaluate(f"{scroller}.scrollWidth - {scroller}.clientWidth")
            boxes = []
            for left in (0, 10 ** 6):                      # the figures scrolled fully left, right
                tab.evaluate(f"{scroller}.scrollLeft = {left}")
                boxes += [cell.bounding_box() for cell in tab.query_selector_all("table.rows .notes")]
        finally:
            browser.close()
    assert fail != passed and na not in (fail, passed)
    assert na_text == "n/a"                                 # uniform × temporal-only
    assert broken == []
    assert overflow > 100                                   # the figures do scroll sideways
    assert len(boxes) == 2 * 4                              # the header and three rows, twice
    for box in boxes:                                       # horizontally within the viewport
        assert box["x"] >= 0 and box["x"] + box["width"] <= width, box
