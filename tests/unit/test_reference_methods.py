"""Reference rows: registered, trainable-as-no-op, and their hands are what they claim."""

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from grip_bench.core.registry import Registry
from grip_bench.data.sequence import Sequence
from grip_bench.methods.api import MethodSpec, TrainContext, load_all, reference_rows
from tests.grab_fixtures import make_sequence

ROWS = ("gt", "perturbed-input", "flat-input", "mean-pose")


@pytest.fixture(scope="module")
def methods() -> Registry[MethodSpec]:
    return load_all()


def _run(methods: Registry[MethodSpec], name: str, seq: Sequence, tmp_path: Path) -> Sequence:
    m = methods.get(name).build()
    ckpt = m.train(tmp_path, tmp_path / f"{name}.pt", TrainContext(profile={}))
    m.load(ckpt)
    return m.predict(seq, None)


def test_reference_rows_are_marked_reference(methods: Registry[MethodSpec]) -> None:
    # gt and the unchanged input bound the scale; flat-input and mean-pose compete
    assert reference_rows() == ("gt", "perturbed-input")
    for name in ROWS:
        spec = methods.get(name)
        assert not spec.trainable and not spec.supports_online
        assert spec.reference == (name in ("gt", "perturbed-input"))
        assert not hasattr(spec, "tables")


@pytest.mark.parametrize("name", ["gt", "perturbed-input"])
def test_identity_rows_return_the_input(
    methods: Registry[MethodSpec], name: str, tmp_path: Path
) -> None:
    seq = make_sequence(T=7)
    out = _run(methods, name, seq, tmp_path)
    for side in ("right", "left"):
        for k, v in seq.hand_params(side).items():
            np.testing.assert_array_equal(out.hand_params(side)[k], v)


@pytest.mark.parametrize("name,check", [
    ("flat-input", lambda p, relaxed: np.allclose(p, 0.0)),
    ("mean-pose", lambda p, relaxed: np.allclose(p, relaxed)),
])
def test_fixed_finger_rows_keep_wrists(
    methods: Registry[MethodSpec],
    name: str,
    check: Callable[[np.ndarray, np.ndarray], bool],
    tmp_path: Path,
) -> None:
    from grip_bench.bodies.hand import ProceduralHand

    seq = make_sequence(T=5)
    out = _run(methods, name, seq, tmp_path)
    for side in ("right", "left"):
        relaxed = ProceduralHand(side).named_pose("relaxed").double().numpy().reshape(45)
        assert check(out.hand_params(side)["hand_pose"], relaxed)
        np.testing.assert_array_equal(
            out.hand_params(side)["transl"], seq.hand_params(side)["transl"]
        )
        np.testing.assert_array_equal(out.hand_params(side)["global_orient"],
                                      seq.hand_params(side)["global_orient"])
    out.validate()


def test_ls_methods_lists_reference_rows(capsys: pytest.CaptureFixture[str]) -> None:
    from grip_bench.cli.main import main

    assert main(["ls", "methods"]) == 0
    out = capsys.readouterr().out
    for name in ("gt", "perturbed-input", "flat-input", "mean-pose"):
        assert name in out
