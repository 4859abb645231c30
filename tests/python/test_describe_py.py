"""`PlannerSettings.describe()` / `SimConfig.describe()` and the classes' docstrings: one row
per field with the serialised default, the range validation enforces, and the same rows as
`nudge settings --format json` and docs/reference/settings.md."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import pytest

import nudge

ROOT = Path(__file__).resolve().parents[2]
CLASSES = [nudge.PlannerSettings, nudge.SimConfig]
RANGE = re.compile(r"^([\[(])(-?[\d.e+-]+|inf), (-?[\d.e+-]+|inf)([\])])$")


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_one_row_per_field_with_the_default(cls: type) -> None:
    rows = cls.describe()
    defaults = {}
    for k, v in cls.default().to_dict().items():
        # The planner settings' groups are dicts of their fields, named `group.field`.
        defaults.update({f"{k}.{f}": x for f, x in v.items()} if isinstance(v, dict) else {k: v})
    assert sorted(r["field"] for r in rows) == sorted(defaults)
    for r in rows:
        assert set(r) == {"field", "unit", "default", "range", "doc"}
        d = defaults[r["field"]]
        assert r["default"] == d and type(r["default"]) is type(d), r
        assert len(r["doc"]) > 10 and r["range"], r


def _outside(lo: float, lo_open: bool, hi: float, hi_open: bool, integer: bool) -> list[float]:
    """Values just outside the range (inclusive ends are stepped over, open ends hit)."""
    step = (lambda v, d: v + d) if integer else (lambda v, d: math.nextafter(v, d * math.inf))
    out = [lo if lo_open else step(lo, -1), hi if hi_open else step(hi, 1)]
    return [v for v in out if not (integer and (v < 0 or math.isinf(v)))]


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_documented_ranges_are_the_validated_ones(cls: type) -> None:
    """Independently of the table: just outside each documented range validation refuses the
    value naming the field, and each closed end is accepted."""
    checked = 0
    for r in cls.describe():
        m = RANGE.match(r["range"])
        if m is None:
            assert isinstance(r["default"], (bool, str)), r
            continue
        lo, hi = float(m[2]), float(m[3])
        integer = isinstance(r["default"], int) and not isinstance(r["default"], bool)
        for v in _outside(lo, m[1] == "(", hi, m[4] == ")", integer):
            with pytest.raises(nudge.SettingsError, match=f"`{r['field']}`"):
                cls(**{r["field"]: int(v) if integer else v})
        for v, closed in ((lo, m[1] == "["), (hi, m[4] == "]")):
            if closed and not math.isinf(v):
                assert getattr(cls(**{r["field"]: int(v) if integer else v}), r["field"]) == v
        checked += 1
    assert checked >= (30 if cls is nudge.PlannerSettings else 7)


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_docstring_lists_every_field(cls: type) -> None:
    doc = cls.__doc__
    for r in cls.describe():
        assert f"\n{r['field']} : " in doc and r["doc"] in doc, r["field"]


def test_cli_prints_the_same_rows() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "nudge", "settings", "--format", "json"],
        capture_output=True, text=True, check=True, timeout=60,
    )
    got = json.loads(done.stdout)
    assert got == {c.__name__: c.describe() for c in CLASSES}


def test_reference_page_has_every_row() -> None:
    page = (ROOT / "docs" / "reference" / "settings.md").read_text()
    for cls in CLASSES:
        for r in cls.describe():
            assert f"| `{r['field']}` |" in page, r["field"]
