"""The calibration report as one self-contained HTML page: the verdict in one line at the top, the estimate with its
1σ and 95 % bounds, what the covariance assumes, the fit's consistency, the observability, every measurement, and
the plots embedded as PNG (no file beside it, nothing fetched from anywhere).
"""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence

from .words import axis_consistency_sentence

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 70em; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.15em; margin-top: 1.6em; }
.verdict { font-size: 1.2em; font-weight: bold; padding: 0.6em 0.9em; border-radius: 6px; }
.usable { background: #e3f4e1; border: 1px solid #6bb463; }
.unusable { background: #fbe4e1; border: 1px solid #d9786a; }
table { border-collapse: collapse; margin: 0.5em 0; } td, th { padding: 0.25em 0.7em; border-bottom: 1px solid #ddd; }
th { text-align: left; background: #f4f4f4; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
figure { margin: 1em 0; } img { max-width: 100%; border: 1px solid #ddd; } figcaption { color: #555; }
"""


def _e(text) -> str:
    return html.escape(str(text))


def _table(header: Sequence[str], rows: Sequence[Sequence[str]], numeric: Sequence[bool]) -> str:
    head = "".join(f"<th>{_e(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f'<td class="num">{_e(c)}</td>' if n else f"<td>{_e(c)}</td>"
                                    for c, n in zip(row, numeric, strict=True)) + "</tr>" for row in rows)
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def _list(lines: Sequence[str]) -> str:
    return "<ul>" + "".join(f"<li>{_e(line)}</li>" for line in lines if line) + "</ul>"


def to_html(report, figures: Sequence[tuple[str, bytes]] = ()) -> str:
    """The page of a :class:`gtsam_rotid.report.CalibrationReport`; ``figures`` are (name, PNG bytes), e.g.
    :func:`gtsam_rotid.plots.report_pngs`."""
    usable = report.verdict.startswith("USABLE")
    parts = ["<!DOCTYPE html>", '<html lang="en"><head><meta charset="utf-8">',
             '<meta name="viewport" content="width=device-width, initial-scale=1">',
             "<title>gtsam_rotid calibration report</title>", f"<style>{_STYLE}</style></head><body>",
             "<h1>Calibration report</h1>",
             f'<p class="verdict {"usable" if usable else "unusable"}" id="verdict">{_e(report.verdict)}</p>',
             _list(report._header_lines()),
             "<h2>Estimate</h2>",
             _table(["", "estimate", "1σ", "95 % (±1.96σ)"], report._estimate_rows(), [False, True, True, True]),
             _list(report._uncertainty_lines()),
             "<h2>Fit consistency</h2>",
             _list([report.chi2.sentence(), f"tested: {report.chi2.what}"]
                   + ([f"note: {report.chi2.note}"] if report.chi2.note else [])
                   + ([] if report.axis_consistency is None else [axis_consistency_sentence(report.axis_consistency)])),
             "<h2>Observability</h2>", _list(report._observability_lines()),
             "<h2>Measurements</h2>",
             _table(["k", "tracks", "points", "RMS (px)", "weight", "rejected", "status"],
                    report._measurement_rows(), [True, True, True, True, True, True, False])]
    rejected = report.rejected_tracks
    parts += ["<h2>Rejected tracks</h2>",
              _list([f"measurement {k}, track {j}: {why}" for k, j, why in rejected]) if rejected else "<p>none</p>"]
    if figures:
        parts.append("<h2>Plots</h2>")
        for name, png in figures:
            data = base64.b64encode(png).decode("ascii")
            parts.append(f'<figure><img alt="{_e(name)}" src="data:image/png;base64,{data}">'
                         f"<figcaption>{_e(name)}</figcaption></figure>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"
