"""The capture-noise model (data.capture_noise): identity, determinism, and measured
statistics of the applied noise against its parameters (GRAB's penetration and jitter)."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

from grip_bench.core.errors import InputError
from grip_bench.core.frames import SIDES
from grip_bench.data.capture_noise import (
    FINGER_RMS_PER_RAD,
    FINGERS,
    MODELS,
    CaptureNoise,
    apply_capture_noise,
    draw,
    resolve_model,
)

GRAB = MODELS["grab"]
NO_JITTER = dataclasses.replace(GRAB, transl_jitter=0.0, pose_jitter=0.0)
JITTER_ONLY = dataclasses.replace(GRAB, penetration_mean=0.0, penetration_std=0.0)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """(library, {object name: sequence}) of SynthGRAB's tiny data (3 sequences)."""
    from grip_bench.data.grab_io import list_sequences, read_grab
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.data.synth.generate import generate

    root = tmp_path_factory.mktemp("noise") / "data"
    generate(root, profile="tiny", seed=0, workers=1, progress=False)
    seqs = {s.obj_name: s for s in map(read_grab, list_sequences(root))}
    return ObjectLibrary(root), seqs


def _grasping(seqs: dict):
    """A sequence whose hand holds a solid object (not a thin-walled cup)."""
    return next(s for name, s in sorted(seqs.items()) if name not in ("cup", "mug"))


def test_the_grab_model_cites_its_numbers():
    assert GRAB.penetration_mean == 0.00325 and GRAB.penetration_std == 0.00068  # S.5
    assert GRAB.penetration_max == 0.0058 and GRAB.transl_jitter == 0.001  # S.5, S.8
    # finger jitter: the finger vertices move sqrt(3) mm rms, as the wrist does
    assert GRAB.pose_jitter * FINGER_RMS_PER_RAD == pytest.approx(np.sqrt(3) * 1e-3, rel=2e-3)
    assert resolve_model("none") is None and resolve_model(GRAB) is GRAB
    with pytest.raises(InputError, match="unknown capture-noise model"):
        resolve_model("vicon")
    with pytest.raises(InputError, match="finite number >= 0"):
        CaptureNoise(-1.0, 0.0, 0.0, 0.0, 0.0)


def test_finger_rms_per_radian_is_what_the_hand_measures():
    """The calibration constant re-measured: i.i.d. pose noise on the relaxed procedural
    hand moves its finger vertices by FINGER_RMS_PER_RAD m rms per radian."""
    import torch

    from grip_bench.bodies.hand import ProceduralHand

    hand = ProceduralHand("right")
    pose = hand.named_pose("relaxed")[None]
    g = torch.Generator().manual_seed(1)
    sigma, n = 0.01, 2000
    with torch.no_grad():
        v0, _ = hand(torch.zeros(1, 3), pose, torch.zeros(1, 3))
        noise = torch.randn(n, 15, 3, generator=g, dtype=pose.dtype) * sigma
        v1, _ = hand(torch.zeros(n, 3), pose.repeat(n, 1, 1) + noise, torch.zeros(n, 3))
    fingers = np.asarray(hand.part_labels) > 0
    rms = float(np.sqrt(((v1 - v0).numpy()[:, fingers] ** 2).sum(-1).mean()))
    assert rms / sigma == pytest.approx(FINGER_RMS_PER_RAD, rel=0.03)


def test_none_is_the_identity(tiny):
    library, seqs = tiny
    seq = _grasping(seqs)
    for model in ("none", None):
        out, stats = apply_capture_noise(seq, model, library, seed=0)
        assert stats == {} and out is not seq
        for side in SIDES:
            for key, a in seq.hand_params(side).items():
                np.testing.assert_array_equal(out.hand_params(side)[key], a)
        np.testing.assert_array_equal(out.body["fullpose"], seq.body["fullpose"])


def test_seeded_and_deterministic(tiny):
    library, seqs = tiny
    seq = _grasping(seqs)
    a, sa = apply_capture_noise(seq, JITTER_ONLY, library, seed=3)
    b, sb = apply_capture_noise(seq, JITTER_ONLY, library, seed=3)
    c, _ = apply_capture_noise(seq, JITTER_ONLY, library, seed=4)
    for side in SIDES:
        np.testing.assert_array_equal(a.hand_params(side)["transl"], b.hand_params(side)["transl"])
        np.testing.assert_array_equal(a.hand_params(side)["hand_pose"],
                                      b.hand_params(side)["hand_pose"])
        assert not np.array_equal(a.hand_params(side)["transl"], c.hand_params(side)["transl"])
    assert sa == sb
    # the draw depends on the sequence's name and the seed only
    other = dataclasses.replace(seq, obj_name="elsewhere")
    np.testing.assert_array_equal(draw(seq, GRAB, 3)["right"]["transl"],
                                  draw(other, GRAB, 3)["right"]["transl"])


def test_jitter_rms_matches_its_parameters(tiny):
    library, seqs = tiny
    seq = _grasping(seqs)
    out, stats = apply_capture_noise(seq, JITTER_ONLY, library, seed=0)
    for side in SIDES:
        dt = out.hand_params(side)["transl"] - seq.hand_params(side)["transl"]
        dp = out.hand_params(side)["hand_pose"] - seq.hand_params(side)["hand_pose"]
        # T x 3 (~800) and T x 45 (~12000) samples: rms within 8 % and 3 %
        assert np.sqrt(np.mean(dt ** 2)) == pytest.approx(GRAB.transl_jitter, rel=0.08)
        assert np.sqrt(np.mean(dp ** 2)) == pytest.approx(GRAB.pose_jitter, rel=0.03)
        assert abs(dt.mean()) < 3 * GRAB.transl_jitter / np.sqrt(dt.size)  # zero mean
        assert stats[side]["transl_rms"] == pytest.approx(np.sqrt(np.mean(dt ** 2)))
        # the body's copy of the hand pose follows (no clean copy left in the file)
        np.testing.assert_allclose(out.body[f"{side}_hand_pose"],
                                   out.hand_params(side)["hand_pose"], atol=1e-6)


def test_drawn_depths_follow_grab():
    """Depths per sequence and hand: mean 3.25 mm, std 0.68 mm, within [0, 5.8] mm."""
    seqs = [SimpleNamespace(name=f"s{i}/obj_use_{i}", n_frames=2) for i in range(3000)]
    d = np.array([draw(s, GRAB, 0)[side]["depth"] for s in seqs for side in SIDES])
    assert d.mean() == pytest.approx(0.00325, abs=3e-5)  # 6000 draws: se 9e-6 m
    assert d.std() == pytest.approx(0.00068, rel=0.05)
    assert d.min() >= 0 and d.max() <= 0.0058


def _contact_depths(seq, noisy, library, model):
    """Independent measurement: per in-contact finger-frame of each hand (its closest
    vertex within contact_distance of the surface in the clean sequence), the mean depth
    (m) of its contact vertices in ``noisy``, and the share of them inside."""
    from grip_bench.bodies.layouts import HAND_PARTS
    from grip_bench.data.posing import hand_poser

    field = library.field(seq.obj_name)
    poser = hand_poser(seq, None)
    out = {}
    for side in SIDES:
        labels = np.asarray(poser.hands[side].part_labels)
        sd = []
        for s in (seq, noisy):
            v = library.world_to_object(s, poser.vertices(side, s.hand_params(side)))
            sd.append(np.asarray(field.signed_distance(v.reshape(-1, 3), far="bound")).reshape(
                v.shape[:2]))
        depths, inside = [], []
        for finger in FINGERS:
            ids = np.flatnonzero(labels == HAND_PARTS.index(finger))
            clean, new = sd[0][:, ids], sd[1][:, ids]
            for t in np.flatnonzero(clean.min(axis=1) <= model.contact_distance):
                sel = clean[t] <= model.contact_distance
                depths.append(-new[t, sel].mean())
                inside.append((new[t, sel] < 0).mean())
        out[side] = (np.array(depths), np.array(inside))
    return out


def test_contact_vertices_penetrate_by_the_drawn_depth(tiny):
    """Every in-contact finger-frame whose depth can be reached has its contact vertices at
    the drawn depth on average (measured independently); those that cannot (a wall thinner
    than twice the depth, an edge) are counted as unreached, and they are a minority."""
    library, seqs = tiny
    seq = _grasping(seqs)
    noisy, stats = apply_capture_noise(seq, NO_JITTER, library, seed=0)
    measured = _contact_depths(seq, noisy, library, NO_JITTER)
    held = [side for side in SIDES if len(measured[side][0])]
    assert held, "the tiny sequence should grasp with some hand"
    for side in held:
        depths, inside = measured[side]
        s = stats[side]
        assert s["finger_frames"] == len(depths)
        assert depths.mean() == pytest.approx(s["contact_depth"], abs=1e-6)
        assert inside.mean() == pytest.approx(s["inside_share"], abs=1e-9)
        exact = np.abs(depths - s["depth"]) < 2e-6
        assert exact.sum() >= len(depths) - s["unreached"]  # every reached one is exact
        assert s["unreached"] < 0.5 * len(depths)
        assert 0.0 < s["depth"] <= GRAB.penetration_max
        assert inside[exact].mean() > 0.9
    # frames without any finger within the fade distance keep their exact pose
    side = held[0]
    same = np.all(noisy.hand_params(side)["hand_pose"] == seq.hand_params(side)["hand_pose"],
                  axis=1)
    assert same.any() and not same.all()


@pytest.mark.slow
def test_a_run_with_capture_noise_builds_a_noisy_dataset_unit(tmp_path):
    """``[run] capture_noise = "grab"``: the dataset unit generates, then applies the model;
    its data hash is of the noisy files and ``capture_noise.json`` holds the statistics."""
    import json

    from grip_bench.bench import runner
    from grip_bench.bench.execute import run_stage
    from grip_bench.bench.plan import make_config
    from grip_bench.data.capture_noise import NOISE_FILE
    from grip_bench.data.grab_io import dataset_hash
    from tests.run_fixtures import tiny_run_profile

    path = tiny_run_profile(tmp_path / "noisy.toml", capture_noise="grab")
    cfg = make_config(str(path), out=tmp_path / "out", workers=1, progress=False)
    st = runner.start(cfg)
    run_stage(st, "data", "dataset", runner.dataset_unit)
    data = st.data_dir(st.plan.data_key)
    record = json.loads((data / NOISE_FILE).read_text(encoding="utf-8"))
    info = st.info(st.plan.data_key)["info"]
    assert record["model"] == "grab" and record["seed"] == 0
    assert record["parameters"]["penetration_mean"] == pytest.approx(0.00325)
    assert info["data_hash"] == dataset_hash(data)
    assert info["capture_noise"] == record["statistics"]
    s = record["statistics"]
    assert s["hands"] == 6 and s["finger_frames"] > 0
    assert s["transl_rms"] == pytest.approx(0.001, rel=0.1)
    assert 0.0 < s["contact_depth_mean"] < 0.0058
