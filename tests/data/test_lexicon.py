import csv
import shutil

import pytest

from aslexp.data.dataset import DataError
from aslexp.data.lexicon import LEXICONS, PROPERTIES, load_lexicon


def test_sizes_and_vocabularies(lexicons):
    assert len(lexicons["asllex1"]) == 993
    assert len(lexicons["asllex2"]) == 2723
    sizes = {"asllex1": dict(sign_type=5, major_location=6, minor_location=33, selected_fingers=10,
                             flexion=9, movement=6),
             "asllex2": dict(sign_type=6, major_location=6, minor_location=37, selected_fingers=12,
                             flexion=7, movement=8)}
    for name, lexicon in lexicons.items():
        for prop in PROPERTIES:
            used = set(lexicon.value_counts(prop)) - {None}
            assert used == set(lexicon.vocabulary(prop)), (name, prop)
            assert len(used) == sizes[name][prop]


def test_missing_values_and_none_movement(lexicons, data_root):
    one, two = lexicons["asllex1"], lexicons["asllex2"]
    assert one.value_counts("selected_fingers")["thumb"] == 54
    assert two.value_counts("selected_fingers")["t"] == 156
    # 'NA' flexion = missing (thumb-only signs); 'None' movement = a real value.
    assert two.value_counts("flexion")[None] == 156
    assert {e.properties["selected_fingers"] for e in two.entries if e.properties["flexion"] is None} == {"t"}
    assert one.value_counts("movement")["None"] == 178
    assert two.value_counts("movement")["None"] == 417
    assert one.value_counts("major_location")["Other"] == 1
    pandas_like = load_lexicon("asllex1", data_root, movement_none_as_missing=True)
    assert pandas_like.value_counts("movement")[None] == 178


def test_unknown_value_names_file_row_column(tmp_path, data_root):
    source = data_root / LEXICONS["asllex1"].relpath
    rows = list(csv.reader(source.open(encoding="utf-8-sig")))
    column = rows[0].index("Movement")
    rows[5][column] = "Wiggly"
    bad = tmp_path / "SignData.csv"
    with bad.open("w", newline="", encoding="utf-8") as handle:
        csv.writer(handle).writerows(rows)
    with pytest.raises(DataError) as error:
        load_lexicon("asllex1", path=bad)
    message = str(error.value)
    for part in (str(bad), rows[5][0], "Movement", "Wiggly", "BackAndForth"):
        assert part in message


def test_missing_file_and_column(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.csv"):
        load_lexicon("asllex2", path=tmp_path / "nope.csv")
    (tmp_path / "x.csv").write_text("EntryID,LemmaID\na,a\n", encoding="utf-8")
    with pytest.raises(DataError, match="SignType.2.0"):
        load_lexicon("asllex2", path=tmp_path / "x.csv")
    with pytest.raises(DataError, match="asllex3"):
        load_lexicon("asllex3")


def test_bom_file_parses_first_column(lexicons, data_root, tmp_path):
    # The 2.0 file starts with a BOM; EntryID must still be found (first row '1_dollar').
    assert lexicons["asllex2"].entries[0].entry_id == "1_dollar"
    shutil.copy(data_root / LEXICONS["asllex2"].relpath, tmp_path / "copy.csv")
    assert len(load_lexicon("asllex2", path=tmp_path / "copy.csv")) == 2723
