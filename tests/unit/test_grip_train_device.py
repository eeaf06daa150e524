"""GRIP training on a device (``train_grip(device=...)``), tested with what a CPU allows.

No GPU here: the CUDA path itself is not run. What is checked: an absent CUDA is a one-line
``InputError`` before any work; a training given a ``torch.device`` feeds every network
float32 inputs on that device, moves its modules only there, and reads nothing back to
the host inside the batch loop (one read per epoch; one per RNet batch for the distance
grids' per-object group sizes); the files a non-CPU training writes (CPU copies of every
state) load on the CPU and resume to the weights of an uninterrupted run; and the plumbed
CPU path writes the session checkpoint's bytes (the plain ``GripMethod`` training).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest
import torch

from grip_bench.core.checkpoint import load_checkpoint, save_checkpoint
from grip_bench.core.errors import InputError
from grip_bench.grip import train as TR
from grip_bench.nn import ddp
from tests.grip_fixtures import tiny_profile

pytestmark = pytest.mark.usefixtures("one_thread")
NO_CUDA = pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
FAKE_GPU = torch.device("cuda")  # only ever handed to the functions that copy to the host


def _sha(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


# --- refusing ------------------------------------------------------------------------------
@NO_CUDA
@pytest.mark.parametrize("device", ["cuda", "cuda:0", torch.device("cuda", 1)])
def test_cuda_without_cuda_is_one_line_before_any_work(tiny_grip_root, tmp_path, device):
    with pytest.raises(InputError) as err:
        TR.train_grip(tiny_grip_root, tmp_path / "g.pt", profile=tiny_profile(),
                      device=device, progress=False, feature_cache=tmp_path / "feat")
    assert err.value.where == "--device"
    assert "CUDA is not available" in str(err.value) and "\n" not in str(err.value)
    assert list(tmp_path.iterdir()) == []  # no features, no partial: nothing started


@pytest.mark.parametrize("device", ["gpu", "", "meta"])
def test_unknown_devices_are_refused(tiny_grip_root, tmp_path, device):
    with pytest.raises(InputError) as err:
        TR.train_grip(tiny_grip_root, tmp_path / "g.pt", profile=tiny_profile(),
                      device=device, progress=False, feature_cache=tmp_path / "feat")
    assert err.value.where == "--device"
    assert list(tmp_path.iterdir()) == []


@NO_CUDA
def test_a_cuda_ddp_job_is_refused_before_its_processes_start(tmp_path):
    from grip_bench.bench.stages.train import train_checkpoint
    from grip_bench.methods.api import TrainContext, load_all

    load_all()
    ctx = TrainContext(profile=tiny_profile(), device="cuda", progress=False)
    with pytest.raises(InputError) as err:
        train_checkpoint("grip", tmp_path, tmp_path / "g.pt", ctx, nproc=2)
    assert err.value.where == "--device"


def test_each_rank_of_a_cuda_job_takes_its_own_gpu_and_the_cpu_stays(monkeypatch):
    assert ddp.train_device("cpu", ddp.Dist(1, 2, 1)) == torch.device("cpu")
    assert ddp.train_device(torch.device("cpu"), ddp.SINGLE) == torch.device("cpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    assert ddp.train_device("cuda", ddp.Dist(1, 2, 1)) == torch.device("cuda", 1)
    assert ddp.train_device("cuda", ddp.SINGLE) == torch.device("cuda")
    assert ddp.backend_for(ddp.train_device("cuda", ddp.Dist(0, 2, 0))) == "nccl"
    ddp.check_gpus(2, "cuda")  # one GPU per process: fine
    with pytest.raises(InputError, match="one GPU each, 2 found") as err:
        ddp.check_gpus(3, "cuda")
    assert err.value.where == "--nproc"
    ddp.check_gpus(3, "cpu")  # gloo processes need no GPU
    # DDP's float64 reductions run where nccl can reach them
    assert TR._collective_device(torch.device("cuda", 1)) == torch.device("cuda", 1)
    assert TR._collective_device(torch.device("cpu")) == torch.device("cpu")


# --- the plumbing, on the CPU ------------------------------------------------------------------
class _HostReads:
    """Counts host reads of tensors (``.cpu()``, ``.numpy()``, ``float()``, ``.item()``,
    ``.tolist()``) made while a batch is in flight: from the end of ``Stage.fetch`` until
    the next fetch or the epoch's one read (``_host_floats``). Adam's reads of its step
    counters are left out: they are CPU tensors on every device (no GPU sync)."""

    NAMES = ("cpu", "numpy", "__float__", "item", "tolist")

    def __init__(self, monkeypatch: pytest.MonkeyPatch):
        self.active, self.batches = False, 0
        self.calls: dict[str, list[str]] = {n: [] for n in self.NAMES}
        for name in self.NAMES:
            monkeypatch.setattr(torch.Tensor, name, self._counting(name, getattr(torch.Tensor,
                                                                                  name)))
        fetch, floats = TR.Stage.fetch, TR._host_floats

        def counted_fetch(stage, split, idx):
            self.active = False  # building a batch reads numpy: not the hot loop
            b = fetch(stage, split, idx)
            self.active, self.batches = True, self.batches + 1
            return b

        def counted_floats(values):
            self.active = False
            return floats(values)

        monkeypatch.setattr(TR.Stage, "fetch", counted_fetch)
        monkeypatch.setattr(TR, "_host_floats", counted_floats)

    def _counting(self, name, method):
        import traceback

        def wrapper(t, *a, **k):
            if self.active:
                frame = traceback.extract_stack(limit=2)[0]
                if "torch/optim" not in Path(frame.filename).as_posix():
                    self.calls[name].append(f"{Path(frame.filename).name}:{frame.name}")
            return method(t, *a, **k)

        return wrapper


def test_device_plumbing_feeds_float32_on_the_device_and_reads_nothing_back_per_batch(
    tiny_grip_root, tiny_grip_checkpoint, tmp_path, monkeypatch
):
    from grip_bench.grip.anet import ANet
    from grip_bench.grip.cnet import CNet
    from grip_bench.grip.rnet import RNet

    want = torch.device("cpu")
    seen_inputs, module_targets, stages = [], [], []

    def check_inputs(module, args):
        if isinstance(module, ANet | CNet | RNet):
            ts = [a for a in args if isinstance(a, torch.Tensor)]
            seen_inputs.append((type(module).__name__, {(t.device, t.dtype) for t in ts}))
            params = {p.device for p in module.parameters()}
            assert params == {want}, params

    hook = torch.nn.modules.module.register_module_forward_pre_hook(check_inputs)
    to = torch.nn.Module.to

    def recording_to(self, *args, **kwargs):
        target = args[0] if args else kwargs.get("device")
        if isinstance(target, str | torch.device):
            module_targets.append(torch.device(target))
        return to(self, *args, **kwargs)

    monkeypatch.setattr(torch.nn.Module, "to", recording_to)
    make = TR._make_stage

    def recording_make(*a, **k):
        stages.append(make(*a, **k))
        return stages[-1]

    monkeypatch.setattr(TR, "_make_stage", recording_make)
    reads = _HostReads(monkeypatch)
    try:
        out = TR.train_grip(tiny_grip_root, tmp_path / "g.pt", profile=tiny_profile(),
                            device=want, progress=False, feature_cache=tmp_path / "feat")
    finally:
        hook.remove()
    # every GRIP network ran, each on float32 inputs on the device only
    assert {name for name, _ in seen_inputs} == {"ANet", "CNet", "RNet"}
    assert all(kinds == {(want, torch.float32)} for _, kinds in seen_inputs), seen_inputs
    assert [s.name for s in stages] == ["anet", "cnet", "rnet"]
    assert all(s.device == want for s in stages)
    assert module_targets and set(module_targets) == {want}  # networks and hand models
    # the batch loop read nothing back, but for the per-object group sizes of RNet's grids
    assert reads.batches > 10
    for name in ("cpu", "numpy", "__float__", "item"):
        assert reads.calls[name] == [], (name, reads.calls[name])
    assert set(reads.calls["tolist"]) <= {"distance.py:grid_signed_distance_many"}
    assert 0 < len(reads.calls["tolist"]) < reads.batches  # RNet's batches only, one each
    # plumbing and instruments change nothing: the session's plain training's bytes
    assert _sha(out) == _sha(tiny_grip_checkpoint)


def test_host_read_counter_sees_a_read_in_the_loop(monkeypatch):
    """The counter of the test above is live (a read after a fetch is counted)."""
    reads = _HostReads(monkeypatch)
    stage = TR.Stage("anet", torch.nn.Linear(2, 2), 4, 0,
                     lambda split, idx: {"x": torch.ones(len(idx), 2)}, None)
    b = stage.fetch("train", np.arange(2))
    float(b["x"].sum())
    b["x"].cpu()
    TR._host_floats([b["x"].sum()])
    b["x"].numpy()  # after the epoch's read: not counted
    assert reads.calls["__float__"] and reads.calls["cpu"] and not reads.calls["numpy"]


# --- files of a non-CPU training --------------------------------------------------------------
def test_files_of_a_device_training_hold_cpu_tensors_and_resume_to_the_same_weights(
    tiny_grip_root, tiny_grip_checkpoint, tmp_path, monkeypatch
):
    """Partials and the shared ANet written through the host-copy path (as a GPU training
    writes them) load on the CPU, keep the optimizer's and the state_dicts' structure, and a
    run killed after CNet's first epoch resumes to the uninterrupted run's weights."""
    save_partial = TR._save_partial
    saved = []

    class Killed(Exception):
        pass

    def gpu_partial(path, nets, configs, states, fp, device=TR.CPU):
        save_partial(path, nets, configs, states, fp, FAKE_GPU)  # the copy-to-host path
        saved.append(sorted(states))
        if "cnet" in states:
            raise Killed

    host_copies = []
    host_copy = TR._host_copy

    def counting_copy(obj, device):
        host_copies.append(device)
        return host_copy(obj, device)

    monkeypatch.setattr(TR, "_save_partial", gpu_partial)
    monkeypatch.setattr(TR, "_device_of", lambda m: FAKE_GPU)  # the shared ANet's device
    monkeypatch.setattr(TR, "_host_copy", counting_copy)
    out, feat = tmp_path / "g.pt", tmp_path / "feat"
    kw = dict(profile=tiny_profile(), progress=False, feature_cache=feat)
    with pytest.raises(Killed):
        TR.train_grip(tiny_grip_root, out, device="cpu", **kw)
    assert saved[-1] == ["anet", "cnet"] and FAKE_GPU in host_copies
    partial = out.with_name(out.name + ".partial")
    payload = torch.load(partial, map_location="meta", weights_only=True)  # no CPU mapping
    cnet = payload["meta"]["stages"]["cnet"]
    tensors = [*_tensors(payload["models"]), *_tensors(payload["meta"])]
    assert tensors and all(t.device.type == "meta" for t in tensors)  # stored as CPU tensors
    raw = torch.load(partial, weights_only=True)
    assert all(t.device.type == "cpu" for t in [*_tensors(raw["models"]),
                                                 *_tensors(raw["meta"])])
    # the stage state keeps its shape: Adam's state by parameter index, the best weights
    assert set(cnet["optimizer"]) == {"state", "param_groups"}
    assert all(isinstance(k, int) for k in raw["meta"]["stages"]["cnet"]["optimizer"]["state"])
    assert set(cnet["best_state"]) == set(load_checkpoint(tiny_grip_checkpoint,
                                                          TR.CONFIG_CLASSES).state["cnet"])
    shared = list(feat.glob("anet-*.pt"))
    assert len(shared) == 1
    anet_file = torch.load(shared[0], weights_only=True)
    assert all(t.device.type == "cpu" for t in anet_file["state"].values())
    assert hasattr(anet_file["state"], "_metadata")  # a state_dict still (module versions)
    # resume (plain CPU path now): the uninterrupted run's weights and curves
    monkeypatch.undo()
    TR.train_grip(tiny_grip_root, out, device="cpu", **kw)
    got, ref = (load_checkpoint(p, TR.CONFIG_CLASSES) for p in (out, tiny_grip_checkpoint))
    for net in TR.STAGES:
        for k, v in ref.state[net].items():
            assert torch.equal(got.state[net][k], v), (net, k)
    assert got.meta["curves"] == ref.meta["curves"]
    assert not partial.exists()


def _tensors(obj):
    if isinstance(obj, torch.Tensor):
        yield obj
    elif isinstance(obj, dict):
        for v in obj.values():
            yield from _tensors(v)
    elif isinstance(obj, list | tuple):
        for v in obj:
            yield from _tensors(v)


def test_a_checkpoint_of_the_device_path_loads_on_the_cpu(tiny_grip_checkpoint):
    nets, meta = TR.load_grip(tiny_grip_checkpoint, "cpu")
    assert set(nets) == set(TR.STAGES)
    for net in nets.values():
        assert {t.device.type for t in (*net.parameters(), *net.buffers())} == {"cpu"}
        assert not net.training
    assert "device" not in meta  # a CPU training's meta (and bytes) as before


def test_a_gpu_checkpoint_never_stands_in_for_a_cpu_one(tiny_grip_checkpoint, tmp_path):
    ck = load_checkpoint(tiny_grip_checkpoint, TR.CONFIG_CLASSES)
    fp = {k: ck.meta[k] for k in ("train_key", "data_hash", "seed", "grip_profile",
                                  "feature_version")}
    assert TR._already_trained(tiny_grip_checkpoint, fp)
    gpu = save_checkpoint(tmp_path / "gpu.pt", model_state=ck.state, configs=ck.configs,
                          meta={**ck.meta, "device": "cuda"})
    assert not TR._already_trained(gpu, fp)
    assert TR._already_trained(gpu, {**fp, "device": "cuda"})
    assert not TR._already_trained(tiny_grip_checkpoint, {**fp, "device": "cuda"})
    # the shared ANet of a GPU training is another file
    cfg = ck.configs["anet"]
    assert TR._shared_anet_path(tmp_path, fp, cfg) != TR._shared_anet_path(
        tmp_path, {**fp, "device": "cuda"}, cfg)


def test_host_copy_keeps_the_cpu_objects_and_copies_the_structure_elsewhere():
    net = torch.nn.Sequential(torch.nn.Linear(3, 2), torch.nn.BatchNorm1d(2))
    sd = net.state_dict()
    assert TR._host_copy(sd, torch.device("cpu")) is sd  # the CPU path pickles the same objects
    copied = TR._host_copy({"s": sd, "l": [torch.ones(1), 2], "t": (torch.zeros(1),)}, FAKE_GPU)
    assert type(copied["s"]) is type(sd) and copied["s"]._metadata == sd._metadata
    assert list(copied["s"]) == list(sd)
    assert isinstance(copied["l"], list) and copied["l"][1] == 2
    assert isinstance(copied["t"], tuple)
    torch.nn.Sequential(torch.nn.Linear(3, 2), torch.nn.BatchNorm1d(2)).load_state_dict(
        copied["s"])


# --- the loss pieces on the device ---------------------------------------------------------------
def test_loss_pieces_keep_their_values_with_device_indices(tiny_grip_root):
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.grip.data import hand_model

    assert hand_model(1.0, "cpu") is hand_model(1.0)  # one cached CPU model
    vert = TR.VertexFn(64, torch.device("cpu"))
    assert isinstance(vert.ids, torch.Tensor) and vert.ids.device.type == "cpu"
    rot = torch.randn(3, 2, 15, 6, generator=torch.Generator().manual_seed(0))
    from grip_bench.geometry.rotations import rotation_6d_to_matrix

    as_numpy = vert.model.vertices(rotation_6d_to_matrix(rot), vert.ids.numpy())
    assert torch.equal(vert(rot), as_numpy)  # a tensor index = the numpy index it replaced
    dist = TR.HandObjectDistance(ObjectLibrary(tiny_grip_root), ["mug"], 32,
                                 device=torch.device("cpu"))
    assert dist.ids.device.type == dist.proximity_ids.device.type == "cpu"
    field = dist.fields[0]
    assert field._grid_on(torch.device("cpu"))[0] is field._vol  # no copy on its own device


def test_grid_distance_of_several_objects_reads_each_group_once(tiny_grip_root):
    from grip_bench.data.library import ObjectLibrary
    from grip_bench.geometry.distance import grid_signed_distance_many

    lib = ObjectLibrary(tiny_grip_root)
    fields = [lib.field("mug"), lib.field("apple")]
    g = torch.Generator().manual_seed(1)
    pts = torch.rand(7, 5, 3, generator=g) * 0.1 - 0.05
    which = torch.tensor([1, 0, 1, 1, 0, 0, 1])
    got = grid_signed_distance_many(fields, which, pts)
    for i in range(7):
        assert torch.equal(got[i], fields[int(which[i])].grid_signed_distance(pts[i]))
