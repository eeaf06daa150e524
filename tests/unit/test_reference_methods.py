"""Reference rows: registered, trainable-as-no-op, and their hands are what they claim."""

import numpy as np
import pytest

from grip_bench.bench.methods import load_all
from tests.grab_fixtures import make_sequence


@pytest.fixture(scope="module")
def methods():
    return load_all()


def _run(methods, name, seq, tmp_path):
    m = methods.get(name).build()
    ckpt = m.train(tmp_path, tmp_path / f"{name}.pt", profile={})
    m.load(ckpt)
    return m.predict(seq, None)


@pytest.mark.parametrize("name", ["gt", "perturbed-input"])
def test_identity_rows_return_the_input(methods, name, tmp_path):
    seq = make_sequence(T=7)
    out = _run(methods, name, seq, tmp_path)
    for side in ("right", "left"):
        for k, v in seq.hand_params(side).items():
            np.testing.assert_array_equal(out.hand_params(side)[k], v)


@pytest.mark.parametrize("name,check", [
    ("flat-input", lambda p, relaxed: np.allclose(p, 0.0)),
    ("mean-pose", lambda p, relaxed: np.allclose(p, relaxed)),
])
def test_fixed_finger_rows_keep_wrists(methods, name, check, tmp_path):
    from grip_bench.bodies.hand import ProceduralHand

    seq = make_sequence(T=5)
    out = _run(methods, name, seq, tmp_path)
    for side in ("right", "left"):
        relaxed = ProceduralHand(side).named_pose("relaxed").double().numpy().reshape(45)
        assert check(out.hand_params(side)["hand_pose"], relaxed)
        np.testing.assert_array_equal(out.hand_params(side)["transl"], seq.hand_params(side)["transl"])
        np.testing.assert_array_equal(out.hand_params(side)["global_orient"],
                                      seq.hand_params(side)["global_orient"])
    out.validate()


def test_ls_methods_lists_reference_rows(capsys):
    from grip_bench.cli.main import main

    assert main(["ls", "methods"]) == 0
    out = capsys.readouterr().out
    for name in ("gt", "perturbed-input", "flat-input", "mean-pose"):
        assert name in out
