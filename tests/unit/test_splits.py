"""Object splits: built-in schemes, splits.json round trip and validation, selection."""

import json

import pytest

from grip_bench.core.errors import InputError
from grip_bench.data.splits import (
    GRAB_OBJECTS,
    GRAB_SPLITS,
    GRIP_SPLITS,
    read_splits,
    sequences_in_split,
    split_of,
    validate_splits,
    write_splits,
)
from tests.grab_fixtures import write_dataset


@pytest.mark.parametrize("splits", [GRIP_SPLITS, GRAB_SPLITS])
def test_builtin_schemes_are_disjoint_and_cover_grab(splits):
    sets = [set(splits[s]) for s in ("train", "val", "test")]
    assert not (sets[0] & sets[1] or sets[0] & sets[2] or sets[1] & sets[2])
    assert set().union(*sets) == set(GRAB_OBJECTS)
    assert len(GRAB_OBJECTS) == len(set(GRAB_OBJECTS)) == 51
    validate_splits(splits)


def test_scheme_contents():
    assert set(GRIP_SPLITS["test"]) == {"mug", "camera", "binoculars", "apple", "toothpaste"}
    assert set(GRIP_SPLITS["val"]) == {"fryingpan", "toothbrush", "elephant", "hand"}
    assert set(GRAB_SPLITS["test"]) == {"mug", "wineglass", "camera", "binoculars", "fryingpan",
                                        "toothpaste"}
    assert set(GRAB_SPLITS["val"]) == {"apple", "toothbrush", "elephant", "hand"}
    assert len(GRIP_SPLITS["train"]) == 42 and len(GRAB_SPLITS["train"]) == 41


def test_round_trip_and_split_of(tmp_path):
    splits = {"train": ["cup", "box"], "val": ["ball"], "test": ["mug"]}
    path = write_splits(tmp_path, splits)
    assert json.loads(path.read_text()) == splits
    assert read_splits(tmp_path) == splits
    assert split_of("ball", splits) == "val"
    with pytest.raises(InputError, match="no split"):
        split_of("spoon", splits)
    assert [p.name for p in tmp_path.iterdir()] == ["splits.json"]


@pytest.mark.parametrize("bad, message", [
    ({"train": ["mug"], "val": [], "test": ["mug"]}, "both 'train' and 'test'"),
    ({"train": [], "val": [], "test": [], "extra": []}, "unknown split names"),
    ({"train": [], "val": []}, "list of object names"),
    ({"train": ["a", 3], "val": [], "test": []}, "list of object names"),
    (["mug"], "should be an object"),
])
def test_invalid_splits(tmp_path, bad, message):
    with pytest.raises(InputError, match=message):
        write_splits(tmp_path, bad)
    (tmp_path / "splits.json").write_text(json.dumps(bad))
    with pytest.raises(InputError, match=message) as e:
        read_splits(tmp_path)
    assert str(tmp_path / "splits.json") in e.value.where


def test_missing_and_unreadable_file(tmp_path):
    with pytest.raises(InputError, match="no splits.json"):
        read_splits(tmp_path)
    assert read_splits(tmp_path, default="grip") == GRIP_SPLITS
    assert read_splits(tmp_path, default="grab") == GRAB_SPLITS
    (tmp_path / "splits.json").write_text("{not json")
    with pytest.raises(InputError, match="JSON"):
        read_splits(tmp_path)


def test_sequences_in_split(tmp_path):
    specs = [
        ("s1", "mug", "lift"),
        ("s1", "cup", "pass"),
        ("s2", "mug", "use"),
        ("s2", "ball", "lift"),
    ]
    write_dataset(tmp_path, specs, T=4,
                  splits={"train": ["cup"], "val": ["ball"], "test": ["mug"]})
    test = [
        p.relative_to(tmp_path / "grab").as_posix() for p in sequences_in_split(tmp_path, "test")
    ]
    assert test == ["s1/mug_lift_1.npz", "s2/mug_use_1.npz"]
    assert len(sequences_in_split(tmp_path, "train")) == 1
    with pytest.raises(InputError, match="unknown split"):
        sequences_in_split(tmp_path, "dev")
