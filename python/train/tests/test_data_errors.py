"""Bad input: every reader raises DataError naming the file and the row; the CLI prints it."""

from __future__ import annotations

import csv
import gzip
from pathlib import Path

import pytest

from nudge_train.cli import main
from nudge_train.data.coifman import read_coifman
from nudge_train.data.commonroad import read_commonroad
from nudge_train.data.errors import DataError
from nudge_train.data.raw import read_raw_ngsim

FIX = Path(__file__).parent / "fixtures"
RAW25 = FIX / "raw" / "peachtree_cut_25col.csv"
COIF = FIX / "i80" / "coifman_cut.csv"


def _rows(path: Path) -> list[list[str]]:
    with open(path, newline="") as fh:
        return list(csv.reader(fh))


def _write(path: Path, rows: list[list[str]]) -> Path:
    with open(path, "w", newline="") as fh:
        csv.writer(fh, lineterminator="\n").writerows(rows)
    return path


def test_raw_missing_column(tmp_path: Path) -> None:
    rows = _rows(RAW25)
    i = rows[0].index("Lane_ID")
    bad = _write(tmp_path / "nolane.csv", [r[:i] + r[i + 1:] for r in rows])
    with pytest.raises(DataError, match=r"nolane\.csv, row 1: missing columns \['lane_id'\]"):
        read_raw_ngsim(bad)


def test_raw_unknown_layout_without_header(tmp_path: Path) -> None:
    rows = _rows(RAW25)[1:]
    bad = tmp_path / "twenty.txt"
    bad.write_text("\n".join(" ".join(r[:20]) for r in rows) + "\n")
    with pytest.raises(DataError, match=r"twenty\.txt, row 1: unknown layout: 20 columns"):
        read_raw_ngsim(bad)


def test_raw_nan_value(tmp_path: Path) -> None:
    rows = _rows(RAW25)
    rows[7][rows[0].index("Local_Y")] = "NaN"
    bad = _write(tmp_path / "nan.csv", rows)
    with pytest.raises(DataError, match=r"nan\.csv, row 8: column Local_Y is 'NaN'"):
        read_raw_ngsim(bad)


def test_raw_not_a_number(tmp_path: Path) -> None:
    rows = _rows(RAW25)
    rows[3][rows[0].index("v_Vel")] = "fast"
    bad = _write(tmp_path / "word.csv", rows)
    with pytest.raises(DataError, match=r"word\.csv, row 4: column v_Vel is not a number"):
        read_raw_ngsim(bad)


def test_raw_empty_and_header_only(tmp_path: Path) -> None:
    empty = tmp_path / "empty.csv"
    empty.write_text("")
    with pytest.raises(DataError, match=r"empty\.csv: empty file"):
        read_raw_ngsim(empty)
    gz = tmp_path / "empty.csv.gz"
    with gzip.open(gz, "wt") as fh:
        fh.write("")
    with pytest.raises(DataError, match="empty file"):
        read_raw_ngsim(gz)
    head = _write(tmp_path / "head.csv", _rows(RAW25)[:1])
    with pytest.raises(DataError, match=r"head\.csv: no data rows"):
        read_raw_ngsim(head)


def test_raw_non_monotonic_time(tmp_path: Path) -> None:
    rows = _rows(RAW25)
    gi = rows[0].index("Global_Time")
    # Row 5 (vehicle 1322 or 352 ...): Global_Time 300 ms off its Frame_ID.
    rows[4][gi] = str(int(rows[4][gi]) + 300)
    bad = _write(tmp_path / "time.csv", rows)
    with pytest.raises(DataError, match=r"time\.csv, row 5: non-monotonic time"):
        read_raw_ngsim(bad)


def test_raw_ragged_row(tmp_path: Path) -> None:
    rows = _rows(RAW25)
    rows[10] = rows[10][:-2]
    bad = _write(tmp_path / "ragged.csv", rows)
    with pytest.raises(DataError, match=r"ragged\.csv, row 11: 23 fields, expected 25"):
        read_raw_ngsim(bad)


def test_raw_duplicate_rows_dropped_and_counted(tmp_path: Path) -> None:
    rows = _rows(RAW25)
    rows = rows + [rows[3], rows[9]]  # exact repeats within one period
    path = _write(tmp_path / "dups.csv", rows)
    tables = read_raw_ngsim(path)
    assert tables[0].notes["duplicate_rows_dropped"] == 2
    assert tables[0].notes["duplicate_keys_in_file"] == 21
    assert sum(len(t) for t in tables) == len(rows) - 1 - 2


def test_coifman_non_monotonic_and_duplicate(tmp_path: Path) -> None:
    rows = _rows(COIF)
    swapped = rows[:]
    swapped[5], swapped[6] = swapped[6], swapped[5]
    with pytest.raises(DataError, match=r"swap\.csv, row 7: non-monotonic time"):
        read_coifman(_write(tmp_path / "swap.csv", swapped))
    dup = rows[:6] + [rows[5]] + rows[6:]
    with pytest.raises(DataError, match=r"dup\.csv, row 7: duplicate frame"):
        read_coifman(_write(tmp_path / "dup.csv", dup))


def test_coifman_unknown_lane(tmp_path: Path) -> None:
    rows = _rows(COIF)
    rows[12][rows[0].index("Lane_ID")] = "8"
    with pytest.raises(DataError, match=r"lane\.csv, row 13: unknown Lane_ID 8"):
        read_coifman(_write(tmp_path / "lane.csv", rows))


def _xml(tmp_path: Path, name: str, text: str) -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _fixture_xml() -> str:
    with gzip.open(FIX / "commonroad" / "USA_US101-1_1_T-1.xml.gz", "rt") as fh:
        return fh.read()


def test_commonroad_errors(tmp_path: Path) -> None:
    text = _fixture_xml()
    with pytest.raises(DataError, match="empty file"):
        read_commonroad(_xml(tmp_path, "e.xml", "  \n"))
    with pytest.raises(DataError, match=r"v\.xml: unknown CommonRoad version '2017a'"):
        read_commonroad(_xml(tmp_path, "v.xml", text.replace('commonRoadVersion="2020a"', 'commonRoadVersion="2017a"')))
    with pytest.raises(DataError, match="unknown layout: root element <scenario>"):
        read_commonroad(_xml(tmp_path, "r.xml", "<scenario/>"))
    with pytest.raises(DataError, match="not valid XML"):
        read_commonroad(_xml(tmp_path, "x.xml", text[:5000]))
    # A NaN coordinate in the first trajectory state.
    i = text.index("<trajectory>")
    j = text.index("<x>", i)
    k = text.index("</x>", j)
    with pytest.raises(DataError, match=rf"n\.xml, row {text.count(chr(10), 0, j) + 1}: .*x is not finite: 'nan'"):
        read_commonroad(_xml(tmp_path, "n.xml", text[:j] + "<x>nan" + text[k:]))
    # Non-monotonic time: the first trajectory state claims step 0 again.
    t = text.index("<exact>1</exact>", i)
    line = text.count("\n", 0, t) + 1
    with pytest.raises(DataError, match=rf"t\.xml, row {line}: obstacle \d+: non-monotonic time"):
        read_commonroad(_xml(tmp_path, "t.xml", text[:t] + "<exact>0</exact>" + text[t + len("<exact>1</exact>"):]))
    # No vehicles.
    a = text.index("<dynamicObstacle")
    b = text.rindex("</dynamicObstacle>") + len("</dynamicObstacle>")
    with pytest.raises(DataError, match="no dynamic obstacles"):
        read_commonroad(_xml(tmp_path, "o.xml", text[:a] + text[b:]))


def test_cli_reports_error_without_traceback(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(["data", "build", "--data-root", str(tmp_path), "--out", str(tmp_path / "out"), "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 2
    assert err.startswith("error: ") and "Traceback" not in err
    assert "no CommonRoad files" in err
