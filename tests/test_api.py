"""The public API: the names the README uses are importable from where it says."""

import re
from pathlib import Path

import gtsam_rotid as rot
from gtsam_rotid import estimate

README = Path(__file__).resolve().parents[1] / "README.md"


def test_calibration_names_at_the_top_level():
    assert rot.calibrate is estimate.calibrate
    for name in ("CalibrationOptions", "CalibrationResult", "CalibrationError", "Method"):
        assert getattr(rot, name) is getattr(estimate, name)
        assert name in rot.__all__
    try:
        rot.no_such_name  # noqa: B018
    except AttributeError as error:
        assert "no_such_name" in str(error)
    else:
        raise AssertionError("an unknown name must raise AttributeError")


def test_every_readme_import_works():
    blocks = re.findall(r"```python\n(.*?)```", README.read_text(encoding="utf-8"), flags=re.S)
    lines = [line.split("#")[0].strip() for block in blocks for line in block.splitlines()]
    imports = [line for line in lines if re.match(r"(import|from) gtsam_rotid\b", line)]
    assert len(imports) >= 5, imports
    for line in imports:
        exec(line, {})  # raises ImportError naming what the README promises and the package lacks
    used = set(re.findall(r"\brot\.([A-Za-z_]\w*)", "\n".join(blocks)))
    assert used, "the README uses the package as rot"
    for name in used:
        assert hasattr(rot, name), f"the README uses rot.{name}, which gtsam_rotid does not have"
