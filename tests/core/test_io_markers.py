"""Marker files: CSV and JSON, tolerant of BOM/CRLF/comments, strict about names and values."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import MarkerError
from core.io.markers import read_markers, write_markers_csv
from core.template import load_template

NAMES = load_template().landmarks


def test_template_has_62_names():
    assert len(NAMES) == 62


def test_csv_basic_and_missing_are_absent():
    text = b"name,x,y,z\nVertex,0,1.7,0\nMenton, 0.0 , 1.5 , 0.1\n"
    m = read_markers(text, "csv", valid_names=NAMES)
    assert set(m) == {"Vertex", "Menton"}
    np.testing.assert_array_equal(m["Menton"], [0, 1.5, 0.1])


def test_csv_bom_crlf_comments_whitespace(tmp_path):
    p = tmp_path / "m.csv"
    p.write_bytes(
        b"\xef\xbb\xbf# exported by scanner\r\n name , x , y , z \r\n\r\n"
        b"# a comment\r\n  Sellion ,1,2,3\r\nToe_tip_L,4,5,6\r\n"
    )
    m = read_markers(p, valid_names=NAMES)
    assert list(m) == ["Sellion", "Toe_tip_L"]
    np.testing.assert_array_equal(m["Toe_tip_L"], [4, 5, 6])


def test_json_dict_and_list():
    m = read_markers(b'{"Vertex": [0, 1.7, 0], "Crotch": [0, 0.8, 0]}', valid_names=NAMES)
    assert set(m) == {"Vertex", "Crotch"}
    m = read_markers(
        b'[{"name": "Vertex", "x": 0, "y": 1.7, "z": 0.05}]', "json", valid_names=NAMES
    )
    np.testing.assert_array_equal(m["Vertex"], [0, 1.7, 0.05])


def test_unknown_names_listed_with_valid_names():
    text = b"name,x,y,z\nVertex,0,1,0\nNose_tip,0,1,0\nBellybutton,0,1,0\n"
    with pytest.raises(MarkerError) as e:
        read_markers(text, "csv", valid_names=NAMES)
    msg = str(e.value)
    assert "Nose_tip" in msg and "Bellybutton" in msg and "Omphalion" in msg
    assert e.value.details["unknown"] == ["Nose_tip", "Bellybutton"]


def test_duplicate_marker():
    with pytest.raises(MarkerError, match="duplicate marker 'Vertex' at line 3"):
        read_markers(b"name,x,y,z\nVertex,0,1,0\nVertex,0,1,0\n", "csv", valid_names=NAMES)
    with pytest.raises(MarkerError, match="duplicate"):
        read_markers(b'{"Vertex": [0,1,0], "Vertex": [0,2,0]}', valid_names=NAMES)


@pytest.mark.parametrize(
    ("row", "match"),
    [
        (b"Vertex,0,abc,0", r"line 2.*non-numeric"),
        (b"Vertex,0,nan,0", r"line 2.*non-finite"),
        (b"Vertex,0,inf,0", r"line 2.*non-finite"),
        (b"Vertex,0,1", r"line 2.*3 columns, expected 4"),
        (b"Vertex,0,1,2,3", r"line 2.*5 columns"),
    ],
)
def test_bad_rows_name_the_line(row, match):
    with pytest.raises(MarkerError, match=match):
        read_markers(b"name,x,y,z\n" + row + b"\n", "csv", valid_names=NAMES)


def test_bad_json():
    with pytest.raises(MarkerError, match="invalid JSON"):
        read_markers(b'{"Vertex": [0,1,', "json", valid_names=NAMES)
    with pytest.raises(MarkerError, match="non-numeric"):
        read_markers(b'{"Vertex": [0,"a",0]}', valid_names=NAMES)
    with pytest.raises(MarkerError, match="2 coordinates, expected 3"):
        read_markers(b'{"Vertex": [0,1]}', valid_names=NAMES)
    with pytest.raises(MarkerError, match="non-finite"):
        read_markers(b'{"Vertex": [0,NaN,1]}', valid_names=NAMES)


def test_empty_and_undecodable():
    with pytest.raises(MarkerError, match="empty"):
        read_markers(b"  \n", "csv", valid_names=NAMES)
    with pytest.raises(MarkerError, match="UTF-8"):
        read_markers(b"name,x,y,z\n\xff\xfa\xfb,1,2,3\n", "csv", valid_names=NAMES)


def test_write_read_roundtrip(tmp_path):
    t = load_template()
    marks = {k: t.V[v] for k, v in t.landmarks.items()}
    p = tmp_path / "all.csv"
    write_markers_csv(p, marks)
    back = read_markers(p, valid_names=NAMES)
    assert list(back) == list(marks)
    for k in marks:
        np.testing.assert_array_equal(back[k], marks[k])
