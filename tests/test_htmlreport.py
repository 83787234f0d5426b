"""The one-line verdict, the self-contained HTML report (plots embedded) and the markdown report that links its
plots."""

from __future__ import annotations

import base64
import re
import shutil
import subprocess
from dataclasses import replace
from html.parser import HTMLParser
from pathlib import Path

import cv2
import numpy as np
import pytest

from gtsam_rotid.cli import main
from gtsam_rotid.estimate import calibrate
from gtsam_rotid.htmlreport import to_html
from gtsam_rotid.plots import report_pngs
from gtsam_rotid.report import make_report
from gtsam_rotid.words import summary, verdict


class Page(HTMLParser):
    """The page's verdict text, its images' sources and every external reference."""

    def __init__(self, text: str):
        super().__init__()
        self.verdict, self.images, self.external, self._in_verdict = "", [], [], False
        self.feed(text)

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if attrs.get("id") == "verdict":
            self._in_verdict = True
        if tag == "img":
            self.images.append(attrs["src"])
        for key in ("src", "href"):
            if key in attrs and not attrs[key].startswith("data:"):
                self.external.append(attrs[key])

    def handle_endtag(self, tag):
        self._in_verdict = False

    def handle_data(self, data):
        if self._in_verdict:
            self.verdict += data


def test_the_verdict_says_usable_and_how_well_or_why_not(reference_weighted, single_crossing):
    _, _, result = reference_weighted
    line = verdict(result)
    assert re.fullmatch(r"USABLE: 1σ at most \d+\.\d\d mm and \d\.\d{3}° on every axis", line), line
    assert summary(result).splitlines()[0] == line
    thin = replace(result, untrusted={"thin_evidence": [2]})
    assert verdict(thin).startswith("NOT USABLE: ") and "measurement 2" in verdict(thin)
    degenerate = calibrate(single_crossing[0])
    assert verdict(degenerate).startswith("NOT USABLE: these arm poses do not determine the calibration; add a pose")
    assert verdict(replace(result, converged=False)).startswith("NOT USABLE: the solver did not converge")


def test_the_html_page_is_self_contained_with_the_verdict_and_the_plots(reference_weighted, tmp_path):
    dataset, _, result = reference_weighted
    pngs = report_pngs(result, dataset)
    assert [name for name, _ in pngs] == ["pose_3d"] + [f"tracks_m{k}" for k in range(len(dataset))] + ["residuals"]
    page = Page(to_html(make_report(result, dataset), pngs))
    assert page.verdict == verdict(result) and not page.external
    assert len(page.images) == len(pngs)
    for src in page.images:
        assert src.startswith("data:image/png;base64,")
        assert base64.b64decode(src.split(",", 1)[1])[:8] == b"\x89PNG\r\n\x1a\n"
    # the command line: one file, nothing beside it; markdown links the plots it writes
    result_path, dataset_path = tmp_path / "result.json", tmp_path / "ds"
    result.save(result_path)
    dataset.save(dataset_path)
    out = tmp_path / "report.html"
    assert main(["report", str(result_path), "--dataset", str(dataset_path), "--format", "html", "-o", str(out)]) == 0
    assert len(Page(out.read_text()).images) == len(pngs) and sorted(p.name for p in tmp_path.iterdir()) == [
        "ds", "report.html", "result.json"]
    md = tmp_path / "notes" / "report.md"
    md.parent.mkdir()
    assert main(["report", str(result_path), "--dataset", str(dataset_path), "--format", "markdown", "-o", str(md),
                 "--plots", str(tmp_path / "plots")]) == 0
    links = re.findall(r"!\[[^]]*\]\(<([^>]+)>\)", md.read_text())
    assert len(links) == len(pngs) and all((md.parent / link).resolve().is_file() for link in links)
    assert all(not Path(link).is_absolute() for link in links)


CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.skipif(CHROMIUM is None, reason="Debian's chromium is not installed here (.ci/run installs it)")
def test_the_page_loads_in_a_headless_browser_and_shows_the_verdict_and_the_plots(reference_weighted, tmp_path):
    dataset, _, result = reference_weighted
    page = tmp_path / "report.html"
    page.write_text(to_html(make_report(result, dataset), report_pngs(result, dataset)), encoding="utf-8")
    shot = tmp_path / "shot.png"
    common = [CHROMIUM, "--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars"]
    run = subprocess.run([*common, "--enable-logging=stderr", "--v=0", "--window-size=1280,11000",
                          f"--screenshot={shot}", page.as_uri()], capture_output=True, text=True, timeout=120)
    problems = [line for line in run.stderr.splitlines() if "CONSOLE" in line or "Failed to load" in line]
    assert run.returncode == 0 and not problems, problems or run.stderr[-2000:]
    dom = subprocess.run([*common, "--dump-dom", page.as_uri()], capture_output=True, text=True, timeout=120).stdout
    assert Page(dom).verdict == verdict(result)
    image = cv2.imread(str(shot))
    assert image is not None and image.shape[:2] == (11000, 1280)
    green = np.all(np.abs(image.astype(int) - [225, 244, 227]) <= 3, axis=2)  # the usable verdict's box (#e3f4e1)
    rows = np.flatnonzero(green.any(axis=1))
    assert green.sum() > 5000 and rows.min() < 300  # at the top of the page
    plots = image[2000:]
    coloured = np.ptp(plots.astype(int), axis=2) > 40  # the plots' colours (the tables are black on white)
    assert coloured.mean() > 0.002 and len(np.unique(plots.reshape(-1, 3), axis=0)) > 200
