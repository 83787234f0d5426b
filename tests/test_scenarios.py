"""Every scenario script (issue 6) runs as a user would, with ``--quick``: exit code 0, one ``VERDICT: PASS`` line,
and its figures written as PNG files into ``--out``.

A scenario's exit code is 1 when one of its judged checks fails, so a regression in the estimators shows up here.
Scenarios that currently fail because of a known estimator problem are marked ``xfail`` (not strict) with the
reason; remove the mark when the estimator is fixed (pytest then reports an XPASS).
"""

import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SCENARIO_DIR = ROOT / "scenarios"
#: Every scenario issue 6 asks for.
REQUIRED = ("reference_jaco2", "noise_monte_carlo", "single_crossing", "minimal_three", "parallel_axes",
            "near_degenerate", "outlier_tracks", "other_arms", "slam_graph", "from_pixels")
SCENARIOS = sorted(p.stem for p in SCENARIO_DIR.glob("*.py") if not p.name.startswith("_"))
#: scenario -> why it fails today (an estimator problem its verdict reports; see the scenario's output). Empty:
#: every scenario passes with --quick.
KNOWN_FAILURES: dict[str, str] = {}
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"


def test_every_required_scenario_exists():
    assert set(REQUIRED) <= set(SCENARIOS)


def params() -> list:
    out = []
    for name in SCENARIOS:
        marks = [pytest.mark.xfail(reason=KNOWN_FAILURES[name], strict=False)] if name in KNOWN_FAILURES else []
        out.append(pytest.param(name, marks=marks, id=name))
    return out


@pytest.mark.parametrize("name", params())
def test_scenario_quick_passes_and_writes_figures(name, tmp_path):
    out = tmp_path / name
    proc = subprocess.run([sys.executable, str(SCENARIO_DIR / f"{name}.py"), "--quick", "--out", str(out)],
                          capture_output=True, text=True, timeout=900, cwd=ROOT)
    tail = f"\n--- stdout (end) ---\n{proc.stdout[-4000:]}\n--- stderr (end) ---\n{proc.stderr[-2000:]}"
    verdicts = [line for line in proc.stdout.splitlines() if line.startswith("VERDICT: ")]
    assert len(verdicts) == 1, "expected exactly one VERDICT line" + tail
    assert proc.returncode == 0, f"exit code {proc.returncode}: {verdicts[0]}" + tail
    assert verdicts[0].startswith("VERDICT: PASS"), tail
    figures = sorted(out.glob("*.png"))
    assert figures, "no figure written" + tail
    for path in figures:
        assert path.read_bytes()[:8] == PNG_SIGNATURE, f"{path.name} is not a PNG"
        assert f"wrote {path}" in proc.stdout, f"{path.name} written but not announced"


def test_scenario_help_and_bad_usage():
    proc = subprocess.run([sys.executable, str(SCENARIO_DIR / "reference_jaco2.py"), "--help"], capture_output=True,
                          text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 0
    for option in ("--quick", "--out", "--seed"):
        assert option in proc.stdout
    proc = subprocess.run([sys.executable, str(SCENARIO_DIR / "reference_jaco2.py"), "--no-such-option"],
                          capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert proc.returncode == 2
