"""``grip-bench render`` and ``grip-bench study make / aggregate`` end to end on tiny fixture
data (6-frame sequences, small frames), and their one-line errors."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from grip_bench.cli.main import main


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    from grip_bench.data.grab_io import read_grab, write_grab
    from tests.grab_fixtures import write_dataset

    root = tmp_path_factory.mktemp("cli_render")
    specs = [("s1", "mug", "lift"), ("s2", "cup", "pass")]
    write_dataset(root / "gt", specs, T=6)
    write_dataset(root / "pred", specs, T=6)
    # a prediction: the right hand shifted by 2 cm (a different picture, same length)
    path = root / "pred" / "grab" / "s1" / "mug_lift_1.npz"
    seq = read_grab(path)
    write_grab(seq.with_hands(right={"transl": seq.rhand["transl"] + 0.02}), path)
    # a prediction one frame short
    write_dataset(root / "short", specs, T=5)
    return root


def _frames(path):
    import imageio.v2 as imageio

    return [f for f in imageio.get_reader(path)]  # list() would ask len(), which is inf


def test_render_writes_mp4_and_gif(folders, tmp_path, capsys):
    out = tmp_path / "sub" / "v.mp4"
    rc = main(["render", "--gt", str(folders / "gt"), "--pred", str(folders / "pred"),
               "--sequence", "s1/mug_lift_1", "--video", str(out), "--gif",
               str(tmp_path / "v.gif"), "--label", "GRIP", "--size", "160x64", "--frames", "1:"])
    assert rc == 0
    printed = capsys.readouterr().out
    assert "v.mp4 (5 frames" in printed and "v.gif (2 frames" in printed
    frames = _frames(out)
    assert len(frames) == 5 and frames[0].shape == (64, 160, 3)
    # below the labels, the shifted hand is the only difference between the panels
    left, right = frames[0][20:, :79].astype(int), frames[0][20:, 81:].astype(int)
    # (rendering the ground truth on both sides leaves ~1 such pixel: compression noise)
    assert (np.abs(left[:, 1:] - right[:, :78]).sum(axis=-1) > 60).sum() >= 10
    assert (tmp_path / "v.gif").stat().st_size < 10_000


@pytest.mark.parametrize("args, message", [
    (["--sequence", "s9/nothing_1"], "error: --gt: no sequence 's9/nothing_1'"),
    (["--pred", "{root}/short"], "frames, but the ground truth has 6"),
    (["--video", "{root}/gt/manifest.json/v.mp4"], "error: --video: cannot write"),
    (["--video", "{tmp}/v.avi"], "error: --video: "),
    (["--size", "641x360"], "error: --size: 641x360: width and height must be even"),
    (["--frames", "7:9"], "error: --frames: selects no frames"),
    (["--video", None], "error: --video: nothing to write"),
])
def test_render_errors(folders, tmp_path, capsys, args, message):
    (folders / "gt" / "manifest.json").write_text("{}")  # a file where a folder would be
    opts = {"--gt": str(folders / "gt"), "--pred": str(folders / "pred"),
            "--sequence": "s1/mug_lift_1", "--video": str(tmp_path / "v.mp4")}
    for k, v in zip(args[::2], args[1::2], strict=True):
        opts[k] = v if v is None else v.format(root=folders, tmp=tmp_path)
    argv = ["render"] + [x for k, v in opts.items() if v is not None for x in (k, v)]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and message in err
    assert not (tmp_path / "v.mp4").exists()


def test_study_make_render_and_aggregate(folders, tmp_path, capsys):
    out = tmp_path / "study"
    argv = ["study", "make", "--gt", str(folders / "gt"), "--pred", f"GRIP={folders / 'pred'}",
            "--out", str(out), "--pairs", "2", "--catch", "2", "--seed", "4", "--size", "64x32"]
    assert main(argv) == 0
    assert "2 pairs + 2 catch trials" in capsys.readouterr().out
    key = pd.read_csv(out / "key.csv", keep_default_na=False)
    assert len(key) == 4 and key["is_catch"].sum() == 2
    for rel in key["video"]:
        frames = _frames(out / rel)
        assert len(frames) == 6 and frames[0].shape == (32, 64, 3)
    # answers: p1 always picks GRIP and the right catch side; p2 picks the wrong catch sides
    rows = []
    for r in key.itertuples():
        if r.is_catch:
            wrong = "left" if r.expected == "right" else "right"
            rows += [("p1", r.pair_id, r.expected), ("p2", r.pair_id, wrong)]
        else:
            grip = "left" if r.left == "GRIP" else "right"
            rows += [("p1", r.pair_id, grip), ("p2", r.pair_id, grip)]
    pd.DataFrame(rows, columns=["participant", "pair_id", "choice"]).to_csv(
        tmp_path / "answers.csv", index=False)
    assert main(["study", "aggregate", "--key", str(out / "key.csv"), "--answers",
                 str(tmp_path / "answers.csv"), "--out", str(tmp_path / "t.md"),
                 "--focus", "GRIP"]) == 0
    assert "1 participant(s) kept, 1 dropped" in capsys.readouterr().out
    table = pd.read_csv(tmp_path / "t.csv")
    assert table.loc[0, "method_a"] == "GRIP" and table.loc[0, "prefer_a_pct"] == 100.0
    assert table.loc[0, "n_answers"] == 2 and table.loc[0, "n_participants"] == 1
    assert "| GRIP vs ground_truth | 100.0 [100.0, 100.0]" in (tmp_path / "t.md").read_text()


def test_study_make_no_render_is_deterministic(folders, tmp_path, capsys):
    def make(out):
        return main(["study", "make", "--gt", str(folders / "gt"), "--pred",
                     f"GRIP={folders / 'pred'}", "--pred", f"TOCH={folders / 'pred'}",
                     "--out", str(out), "--pairs", "12", "--catch", "3", "--seed", "1",
                     "--no-render"])

    assert make(tmp_path / "a") == 0 and make(tmp_path / "b") == 0
    assert (tmp_path / "a" / "key.csv").read_bytes() == (tmp_path / "b" / "key.csv").read_bytes()
    assert not (tmp_path / "a" / "videos").exists()
    key = pd.read_csv(tmp_path / "a" / "key.csv")
    assert len(key) == 15 and key["is_catch"].sum() == 3


def test_study_errors(folders, tmp_path, capsys):
    base = ["study", "make", "--gt", str(folders / "gt"), "--out", str(tmp_path / "s"),
            "--pairs", "2", "--seed", "0", "--no-render"]
    assert main(base + ["--pred", f"GRIP={folders / 'short'}"]) == 1
    assert "frames, but the ground truth has 6" in capsys.readouterr().err
    assert main(base + ["--pred", f"GRIP={tmp_path / 'none'}"]) == 1
    assert "error: --pred GRIP=" in capsys.readouterr().err
    assert main(["study", "aggregate", "--key", str(tmp_path / "nokey.csv"), "--answers",
                 str(tmp_path / "a.csv"), "--out", str(tmp_path / "t.md")]) == 1
    assert capsys.readouterr().err.startswith(f"error: {tmp_path / 'nokey.csv'}: no such file")
    with pytest.raises(SystemExit) as e:
        main(base + ["--pred", "no-equals-sign"])
    assert e.value.code == 2
