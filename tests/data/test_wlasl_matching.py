import json

import pytest

from aslexp.data.dataset import DataError
from aslexp.data.matching import match_glosses, normalise_gloss
from aslexp.data.wlasl import load_class_list, load_nslt, load_wlasl


def test_wlasl_counts(wlasl, data_root):
    assert len(wlasl.glosses) == 2000
    assert len(wlasl.instances) == 21083
    assert wlasl.by_video_id()["69241"].gloss == "book"
    assert {i.split for i in wlasl.instances} == {"train", "val", "test"}
    classes = load_class_list(data_root)
    assert len(classes) == 2000 and classes[:2] == ["book", "drink"]
    nslt = load_nslt(100, data_root)
    assert len({item.label for item in nslt.values()}) == 100
    with pytest.raises(DataError, match="50"):
        load_nslt(50, data_root)


def test_bad_wlasl_file(tmp_path):
    bad = tmp_path / "w.json"
    bad.write_text(json.dumps([{"gloss": "x", "instances": [{"video_id": "1"}]}]))
    with pytest.raises(DataError, match="split"):
        load_wlasl(path=bad)
    with pytest.raises(FileNotFoundError, match="missing.json"):
        load_wlasl(path=tmp_path / "missing.json")


def test_normalise():
    assert normalise_gloss(" Candy_2 ") == "candy"
    assert normalise_gloss("thank_you") == "thank you"
    assert normalise_gloss("1_dollar") == "1 dollar"


@pytest.mark.parametrize("name, glosses, videos, ambiguous",
                         [("asllex1", 802, 10051, 30), ("asllex2", 1383, 15911, 203)])
def test_published_overlap(wlasl, lexicons, name, glosses, videos, ambiguous):
    result = match_glosses(wlasl, lexicons[name])
    assert (result.num_glosses, result.num_videos, len(result.ambiguous)) == (glosses, videos, ambiguous)


def test_ambiguity_rule_and_near_misses(wlasl, lexicons):
    one = match_glosses(wlasl, lexicons["asllex1"]).matches
    two = match_glosses(wlasl, lexicons["asllex2"]).matches
    assert one["candy"].entry.entry_id == "candy_1" and one["candy"].candidates == ("candy_1", "candy_2")
    assert one["movie"].entry.entry_id == "movie"  # exact EntryID beats 'movies' (LemmaID movie)
    assert two["drink"].entry.entry_id == "drink"  # no suffix counts as 0 < 2
    assert two["cool"].entry.entry_id == "cool_1"
    assert "ice cream" not in one and "don't want" not in two  # documented near misses
