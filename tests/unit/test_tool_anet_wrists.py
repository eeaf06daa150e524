"""tools/anet_wrists.py: ANet's wrist-translation error per hand, on fixture sequences."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from grip_bench.core.checkpoint import save_checkpoint
from grip_bench.grip import train as T
from tests.grip_fixtures import holding_sequence, tiny_profile, write_grip_dataset
from tools.anet_wrists import load_anet, main, probe, wrist_errors


def _nets():
    configs = T.build_configs(tiny_profile()["grip"], T.Variant())
    return configs, T._build_nets(configs, 0, {})


def _seqs():
    return [holding_sequence(16, i, "mug", "lift", "s1") for i in range(2)]


def test_an_identity_anet_leaves_the_wrists_where_they_are():
    _, nets = _nets()  # a fresh ANet's head is zero: the arms pass through unchanged
    err = wrist_errors(nets["anet"], _seqs())
    assert set(err) == {"left", "right"}
    assert max(err.values()) < 1e-3  # mm: the FK round trip only


def test_the_error_is_the_mean_over_sequences_of_each_sequences_mean():
    _, nets = _nets()
    anet = nets["anet"]
    with torch.no_grad():
        anet.decoder.head.bias.normal_(0.0, 0.05, generator=torch.Generator().manual_seed(0))
    seqs = _seqs()
    err = wrist_errors(anet, seqs)
    each = [wrist_errors(anet, [s]) for s in seqs]  # one sequence at a time: no batching
    assert min(err.values()) > 0.1
    for side in ("left", "right"):
        assert err[side] == pytest.approx(np.mean([e[side] for e in each]), rel=1e-4)


def test_weights_load_into_a_checkpoints_anet_and_the_cli_prints_both(tmp_path, capsys):
    configs, nets = _nets()
    ckpt = tmp_path / "grip.ckpt"
    save_checkpoint(ckpt, model_state={k: m.state_dict() for k, m in nets.items()},
                    configs=configs, meta={})
    with torch.no_grad():
        nets["anet"].decoder.head.bias.fill_(0.02)
    weights = tmp_path / "anet.pt"
    torch.save(nets["anet"].state_dict(), weights)
    data = write_grip_dataset(tmp_path / "data")
    res = probe(data, [ckpt], [(weights, ckpt)], split="test")
    plain, moved = res[str(ckpt)], res[f"{weights}@{ckpt}"]
    assert max(plain.values()) < 1e-3 < min(moved.values())
    assert load_anet(ckpt) is not load_anet(ckpt)  # fresh objects: no frozen copy reused
    assert main([str(data), str(ckpt), "--weights", f"{weights}@{ckpt}"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert len(out) == 2 and out[0].startswith(str(ckpt)) and "right" in out[1]
