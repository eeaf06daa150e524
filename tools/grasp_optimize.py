"""Can a global, force-closure-driven grasp optimiser make grasps the hold test holds?

SynthGRAB's candidates are the limit on the objects that fail the articulated hold test
(docs/physics_hold.md, "Measured in s43" and "s49": an oracle over every candidate still
drops most one-handed grasps of the binoculars, the mugs and the medium cubes, and a local
refinement toward force closure changed nothing). This probe searches globally instead, for
SynthGRAB's own procedural hand (``GraspSynthesizer``'s light hand, scale 1), in the
object's frame (y up, the table at ``gs.table_y``). Per restart (batched, seeded) the wrist
starts outside the object along an approach from above or the side, the palm toward it, the
fingers in an open pre-shape; Adam then moves the wrist (6D rotation and position) and the
15 x 3 local finger angles (projected into the hand's joint limits after every step) down

    E = w_dis E_dis + r(k) w_fc E_fc + w_lift E_lift + w_pen(k) (E_pen + E_table)
        + w_prior E_prior                              (weights: ``WEIGHTS``)

- ``E_dis``: the restart's contact pads (the thumb's and index's always; the middle's, the
  ring's and a palm point in some restarts: ``PATTERNS`` in turn) pulled onto the surface,
  ``sum |d_i| + DIS_SQUARE d_i^2`` in cm (``d_i`` the exact signed distance, linearised at
  the closest point: its gradient is the normal);
- ``E_fc``: force closure of unit pushes along the inward normals ``u_i`` (central
  differences of the distance grid, ``NORMAL_STEP``, differentiable in the pad positions):
  ``|sum u_i|^2 + |sum (x_i - com) x u_i / r|^2`` (``r``: half the box diagonal); its weight
  ``r(k)`` grows from 0 to 1 over the first ``FC_RAMP`` of the steps (the hand reaches
  the object first);
- ``E_lift``: gravity: at ``GRIP_N`` newtons a contact (about what the test's capped servos
  press with), friction mu = ``SIM_FRICTION`` and the suite's density, each contact can lift
  at most ``u_i . y + mu |u_i x y|`` per newton; ``relu(weight / GRIP_N - sum)^2``;
- ``E_pen``: squared depth (mm) of every hand vertex past ``PEN_MARGIN`` outside the surface
  (exact distances, linearised, within ``NEAR``: the 2 mm grid misses thin walls);
  ``E_table``: squared depth (mm) under ``table + 5 mm``; their weight grows geometrically
  from ``pen0`` to ``pen1``;
- ``E_prior``: squared distance (rad) of the finger angles to their start, abduction and
  twist weighted ``PRIOR_AXES``.

Adam (betas 0.9, 0.99; learning rates decaying to a tenth, cosine) runs every restart at
once in float64 on the CPU; the joint limits are kept by projection.

Afterwards every restart's full hand is measured exactly: valid as SynthGRAB's grasps are
(at most ``MAX_PENETRATION`` deep, ``TABLE_CLEARANCE`` above the table) and touching with
the thumb and one more finger within ``HOLD_TOUCH``; the valid ones run the articulated
hold test (``metrics.hold``: the object in its own frame, gravity along -y, mu = 1, the
suite's density). Nothing here changes the data.

With ``--mass-factors`` and ``--grips`` every valid restart is also held with the object
that many times as heavy and the finger servos that many times as strong (is a grasp that
falls short of force, or of geometry? docs/physics_hold.md, "Measured in s56").

    python tools/grasp_optimize.py DATA [--objects mug ...] [--side right] [--restarts 64]
                                   [--steps 300] [--seed 0] [--mass-factors 1 0.1]
                                   [--grips 1 3] [--json]
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import grip_bench  # noqa: F401  (first: it pins the numerics, docs/reproducibility.md)

# isort: split
import numpy as np

from grip_bench.geometry.rotations import rotation_6d_to_matrix

OBJECTS = ("binoculars", "binoculars_2", "binoculars_3", "mug", "mug_2", "cubemedium_2",
           "cubemedium_3")
PADS = ("thumb", "index", "middle", "ring", "palm")
# contact sets the restarts cycle through (indices into PADS)
PATTERNS = ((0, 1, 2), (0, 1), (0, 1, 2, 3), (0, 1, 2, 3, 4))
# (distal bone, its tip keypoint, the pad's rest-normal direction) per finger pad
_PAD_BONES = {"thumb": (15, 16, (0.0, -0.55, -0.85)), "index": (3, 17, (0.0, -1.0, 0.0)),
              "middle": (6, 18, (0.0, -1.0, 0.0)), "ring": (12, 19, (0.0, -1.0, 0.0))}
GRIP_N = 1.5  # N; the push of one contact assumed by E_lift
PEN_MARGIN = 0.5  # mm; E_pen counts vertices nearer the surface than this, or inside
NEAR = 0.006  # m; vertices the grid puts nearer than this get the exact distance
NORMAL_STEP = 0.003  # m; central-difference step of the closure normals
FC_RAMP = 0.5  # of the steps: the closure weight grows linearly to its full value by then
PRIOR_AXES = (1.0, 10.0, 10.0)  # the prior's weights on flexion, abduction and twist
MIN_SIN_EL = 0.0  # lowest approach elevation's sine (0: level with the object's aim)
DIS_SQUARE = 1.0  # weight of the squared distance (cm^2) beside the absolute one (cm)
START_GAP = 0.015  # m; the palm's distance outside the object's extent at the start
WEIGHTS = dict(dis=3.0, fc=5.0, lift=0.3, prior=0.05, pen0=1.0, pen1=30.0)


@dataclass
class Settings:
    restarts: int = 64
    steps: int = 300
    seed: int = 0
    lr_rot: float = 0.02
    lr_t: float = 0.05  # cm a step
    lr_local: float = 0.02  # rad a step


def pad_vertices(hand) -> np.ndarray:
    """Vertex ids (5,) of the thumb, index, middle and ring pads and a palm point of the
    procedural hand: per finger the vertex of the distal bone 60 % along it whose rest normal
    faces the pad direction most (``bodies.pinch``'s rule); the palm's: the palmar vertex of
    the wrist bone nearest the point 60 % from the wrist to the middle finger's base."""
    import torch

    from grip_bench.geometry.pieces import vertex_normals

    with torch.no_grad():
        v, j = hand(None, hand.template_vertices.new_zeros(1, 15, 3).double(), None)
    v, j = v[0].double().numpy(), j[0].double().numpy()
    n = vertex_normals(v, np.asarray(hand.faces))
    bones = np.asarray(hand.bone_ids)
    out = []
    for f in PADS[:4]:
        bone, tip, d = _PAD_BONES[f]
        ids = np.flatnonzero(bones == bone)
        seg = j[tip] - j[bone]
        frac = (v[ids] - j[bone]) @ seg / (seg @ seg)
        out.append(int(ids[np.argmax(n[ids] @ np.asarray(d) - 3.0 * np.abs(frac - 0.6))]))
    ids = np.flatnonzero((bones == 0) & (n[:, 1] < -0.8))
    aim = 0.4 * j[0] + 0.6 * j[4]
    out.append(int(ids[np.argmin(np.linalg.norm((v[ids] - aim)[:, [0, 2]], axis=1))]))
    return np.asarray(out)


def closure(x, u, mask, com, radius: float):
    """``E_fc`` per restart (B,): contacts ``x`` (B, K, 3), unit inward normals ``u`` (B, K,
    3), ``mask`` (B, K) the active ones; torques about ``com`` (3,) over ``radius``."""
    import torch

    m = mask[..., None]
    force = (m * u).sum(1)
    torque = (m * torch.cross(x - com, u, dim=2)).sum(1) / radius
    return (force ** 2).sum(1) + (torque ** 2).sum(1)


def lift(u, mask, need: float, mu: float):
    """``E_lift`` per restart (B,): the upward force the active contacts can make per newton
    of push (normal ``u . y`` plus friction ``mu |u x y|``) short of ``need``."""
    import torch

    up = u[..., 1]
    cap = up + mu * torch.sqrt((1.0 - up ** 2).clamp_min(1e-9))
    return torch.relu(need - (mask * cap).sum(1)) ** 2


class Problem:
    """One object and one hand: the energy's fixed pieces."""

    def __init__(self, mesh, df, side: str, table_y: float, density: float):
        import torch

        from grip_bench.core import constants as C
        from grip_bench.data.synth import grasp as G

        self.mesh, self.df, self.side, self.table_y = mesh, df, side, float(table_y)
        self.full = G._light_hand(side, 1.0)[0]
        self.hand = self.full
        self.pads = pad_vertices(self.full)
        self.pad_rows = torch.as_tensor(self.pads)
        self.lower = torch.as_tensor(np.asarray(self.full.joint_limits.lower, float))
        self.upper = torch.as_tensor(np.asarray(self.full.joint_limits.upper, float))
        self.com = np.asarray(mesh.center_mass, float)
        self.radius = float(np.linalg.norm(mesh.extents) / 2)
        self.weight = float(density * abs(mesh.volume) * 9.81)
        self.mu = float(C.SIM_FRICTION)
        self.open = G.preshape_local("power")
        self.prior_axes = torch.as_tensor(PRIOR_AXES, dtype=torch.float64)

    # -- start ---------------------------------------------------------------------------
    def starts(self, n: int, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Initial wrist rotations (n, 3, 3), positions (n, 3) and local poses (n, 15, 3):
        approach directions from above and the sides (elevation 0-90 degrees, uniform on the
        hemisphere), a random roll about them, aimed at a point jittered within the middle
        half of the object's box; the palm ``START_GAP`` beyond the object's extent along the
        approach and every hand vertex a third of that at least (moved back along it); the
        fingers in the open pre-shape, a little flexed at random, the thumb half to fully
        turned toward the pinch's opposition."""
        from grip_bench.data.synth import grasp as G

        rng = np.random.default_rng(seed)
        v = np.asarray(self.mesh.vertices, float)
        lo, hi = self.mesh.bounds
        pinch = G.preshape_local("precision")
        R, t, local, ds = [], [], [], []
        palm0 = self._palm_rest()
        for _ in range(n):
            el = np.arcsin(rng.uniform(MIN_SIN_EL, 1.0))  # uniform on the upper hemisphere
            az = rng.uniform(0.0, 2 * np.pi)
            d = np.array([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)])
            aim = 0.5 * (lo + hi) + rng.uniform(-0.25, 0.25, 3) * (hi - lo)
            nrm = -d
            ref = rng.normal(size=3)
            f = ref - (ref @ nrm) * nrm
            f /= np.linalg.norm(f)
            Rk = G._hand_rotation(self.side, f, nrm)
            reach = float(((v - aim) @ d).max()) + START_GAP
            palm = aim + reach * d
            R.append(Rk)
            t.append(palm - Rk @ palm0)
            lk = self.open.copy()
            for fng in ("index", "middle", "ring", "pinky"):
                for jj in G.CHAINS[fng]:
                    lk[jj, 0] += np.radians(rng.uniform(5.0, 25.0))
            a = rng.uniform(0.5, 1.0)
            for jj in G.CHAINS["thumb"]:
                lk[jj] = (1 - a) * self.open[jj] + a * pinch[jj]
            local.append(np.clip(lk, self.lower.numpy(), self.upper.numpy()))
            ds.append((d, reach - START_GAP + float(aim @ d)))
        R, t, local = np.stack(R), np.stack(t), np.stack(local)
        hv, _ = G._pose(self.full, R, t, local)
        for k, (d, plane) in enumerate(ds):  # the whole hand beyond the object's extent
            t[k] += max(0.0, plane + START_GAP / 3 - float((hv[k] @ d).min())) * d
        return R, t, local

    def _palm_rest(self) -> np.ndarray:
        """The palm point in the hand frame at the open pre-shape (3,)."""
        from grip_bench.data.synth import grasp as G

        v, _ = G._pose(self.full, np.eye(3)[None], np.zeros((1, 3)), self.open[None])
        return v[0, self.pads[4]]

    # -- energy --------------------------------------------------------------------------
    def pose(self, x6, t, local):
        """Hand vertices (B, V, 3) in the object frame."""
        R = rotation_6d_to_matrix(x6)
        v, _ = self.hand._lbs(self.hand.from_local(local), R, t)
        return v

    def normals(self, p):
        """Unit outward normals (N, 3) at points (N, 3): central differences of the grid
        (differentiable in ``p``), the exact pseudonormal direction where the grid has none."""
        import torch

        h = NORMAL_STEP
        eye = torch.eye(3, dtype=p.dtype) * h
        q = torch.cat([p[:, None] + eye, p[:, None] - eye], 1)  # (N, 6, 3)
        s = self.df.grid_signed_distance(q).to(p.dtype)
        g = s[:, :3] - s[:, 3:]
        inside = torch.as_tensor(self.df.within_grid(p.detach().numpy()))
        _, c, nx = self.df.exact_contacts(p.detach().numpy())
        nx = torch.as_tensor(nx / np.maximum(np.linalg.norm(nx, axis=1, keepdims=True), 1e-12))
        g = torch.where((inside & (g.norm(dim=1) > 1e-6 * h))[:, None], g, nx)
        return g / g.norm(dim=1, keepdim=True)

    def signed(self, v):
        """Signed distances (B, V) of points (B, V, 3): exact (libigl) where the grid reads
        under ``NEAR`` (thin walls are below the 2 mm grid's resolution), linearised at the
        closest point so the gradient is the normal; the grid's value elsewhere."""
        import torch

        flat = v.reshape(-1, 3)
        out = self.df.grid_signed_distance(flat).to(flat.dtype)
        near = np.flatnonzero(out.detach().numpy() < NEAR)
        if len(near):
            p = flat[near]
            _, c, n = self.df.exact_contacts(p.detach().numpy())
            n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            d = ((p - torch.as_tensor(c)) * torch.as_tensor(n)).sum(1)
            out = out.index_put((torch.as_tensor(near),), d)
        return out.reshape(v.shape[:-1])

    def energy(self, x6, t, local, mask, local0, w_pen: float, w_fc: float = 1.0):
        """Per-restart total (B,) and its terms (dict of (B,))."""
        import torch

        v = self.pose(x6, t, local)
        B = v.shape[0]
        x = v[:, self.pad_rows]  # (B, 5, 3)
        flat = x.reshape(-1, 3)
        d, c, n = self.df.exact_contacts(flat.detach().numpy())
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        d_lin = ((flat - torch.as_tensor(c)) * torch.as_tensor(n)).sum(1).reshape(B, -1)
        u = -self.normals(flat).reshape(B, -1, 3)
        terms = {
            "dis": (mask * (d_lin.abs() * 100.0 + DIS_SQUARE * (d_lin * 100.0) ** 2)).sum(1),
            "fc": closure(x, u, mask, torch.as_tensor(self.com), self.radius),
            "lift": lift(u, mask, self.weight / GRIP_N, self.mu),
            "pen": (torch.relu(PEN_MARGIN - self.signed(v) * 1e3) ** 2).sum(1),
            "table": (torch.relu((self.table_y + 0.005 - v[..., 1]) * 1e3) ** 2).sum(1),
            "prior": (((local - local0) ** 2) * self.prior_axes).sum((1, 2)),
        }
        w = WEIGHTS
        total = (w["dis"] * terms["dis"] + w_fc * w["fc"] * terms["fc"] + w["lift"] * terms["lift"]
                 + w_pen * (terms["pen"] + terms["table"]) + w["prior"] * terms["prior"])
        return total, terms


def masks(n: int) -> np.ndarray:
    """The contact set of each restart (n, 5) (``PATTERNS`` in turn)."""
    m = np.zeros((n, len(PADS)))
    for k in range(n):
        m[k, list(PATTERNS[k % len(PATTERNS)])] = 1.0
    return m


def optimise(problem: Problem, settings: Settings) -> dict:
    """Adam over every restart at once; the final wrists, poses, masks and energies."""
    import torch

    R0, t0, local0 = problem.starts(settings.restarts, settings.seed)
    f64 = dict(dtype=torch.float64)
    x6 = torch.tensor(np.concatenate([R0[:, :, 0], R0[:, :, 1]], 1), **f64).requires_grad_()
    dt = torch.zeros(len(t0), 3, **f64).requires_grad_()  # cm
    local = torch.tensor(local0, **f64).requires_grad_()
    base, prior = torch.tensor(t0, **f64), torch.tensor(local0, **f64)
    mask = torch.tensor(masks(settings.restarts), **f64)
    opt = torch.optim.Adam([{"params": [x6], "lr": settings.lr_rot},
                            {"params": [dt], "lr": settings.lr_t},
                            {"params": [local], "lr": settings.lr_local}], betas=(0.9, 0.99))
    lrs = [g["lr"] for g in opt.param_groups]
    w0, w1 = WEIGHTS["pen0"], WEIGHTS["pen1"]
    first = None
    for step in range(settings.steps):
        frac = step / max(settings.steps - 1, 1)
        w_pen = w0 * (w1 / w0) ** frac
        for g, lr in zip(opt.param_groups, lrs, strict=True):  # cosine decay to a tenth
            g["lr"] = lr * (0.1 + 0.45 * (1.0 + np.cos(np.pi * frac)))
        total, terms = problem.energy(x6, base + 0.01 * dt, local, mask, prior, w_pen,
                                      min(1.0, frac / FC_RAMP) if FC_RAMP > 0 else 1.0)
        if first is None:
            first = {k: v.detach().numpy().copy() for k, v in terms.items()}
            first["total"] = total.detach().numpy().copy()
        opt.zero_grad()
        total.sum().backward()
        opt.step()
        with torch.no_grad():  # the joint limits: projected
            local.copy_(torch.maximum(torch.minimum(local, problem.upper), problem.lower))
    with torch.no_grad():
        total, terms = problem.energy(x6, base + 0.01 * dt, local, mask, prior, w1)
        R = rotation_6d_to_matrix(x6).numpy()
    return dict(R=R, t=(base + 0.01 * dt).detach().numpy(), local=local.detach().numpy(),
                mask=mask.numpy(), first=first, final={**{k: v.numpy() for k, v in
                                                          terms.items()},
                                                       "total": total.numpy()})


def touching(parts: list[str]) -> bool:
    """Whether the parts within ``HOLD_TOUCH`` include the thumb and one more finger."""
    return "thumb" in parts and any(f in parts for f in ("index", "middle", "ring", "pinky"))


DEFAULT_VARIANT = (1.0, 1.0)  # (mass factor, grip factor): the test as the run runs it


def variant_name(mass: float, grip: float) -> str:
    return f"{mass:g}x mass, {grip:g}x grip"


def judge(problem: Problem, res: dict, hold_test: bool = True,
          variants: tuple[tuple[float, float], ...] = (DEFAULT_VARIANT,)) -> list[dict]:
    """Per restart: depth, lowest point above the table, touching parts, valid, held.

    ``variants``: (mass factor, grip factor) pairs each valid restart is held at (the
    object's density and ``metrics.hold.servo_strength`` scaled): ``held_at`` maps
    :func:`variant_name` to the verdict; ``held`` and the other fields are the first
    variant's."""
    from grip_bench.bodies.layouts import HAND_PARTS
    from grip_bench.core import constants as C
    from grip_bench.data.synth import grasp as G

    full = problem.full
    v, j = G._pose(full, res["R"], res["t"], res["local"])
    parts = np.asarray(full.part_labels)
    rows = []
    for c in range(len(v)):
        sd = problem.df.exact_signed_distance(v[c])
        depth = max(-float(sd.min()), 0.0)
        low = float(v[c][:, 1].min() - problem.table_y)
        near = [HAND_PARTS[p] for p in range(len(HAND_PARTS))
                if sd[parts == p].min() <= C.HOLD_TOUCH]
        touch = touching(near)
        valid = bool(depth <= G.MAX_PENETRATION and low >= G.TABLE_CLEARANCE and touch)
        row = dict(restart=c, contacts=[PADS[k] for k in np.flatnonzero(res["mask"][c])],
                   touching=near, depth_mm=1e3 * depth, low_mm=1e3 * low, valid=valid,
                   energy_start=float(res["first"]["total"][c]),
                   energy_end=float(res["final"]["total"][c]),
                   closure_end=float(res["final"]["fc"][c]), held=None)
        if valid and hold_test:
            row.update(_hold(problem, v[c], j[c], sd, variants))
        rows.append(row)
    return rows


def _hold(problem: Problem, v: np.ndarray, j: np.ndarray, sd: np.ndarray,
          variants: tuple[tuple[float, float], ...] = (DEFAULT_VARIANT,)) -> dict:
    """The articulated hold test of one posed full hand in the object's frame, at each
    (mass factor, grip factor) of ``variants`` (a scene per mass)."""
    from grip_bench.core import constants as C
    from grip_bench.metrics.hold import hand_scene, hold
    from tools.probe_cli import posed_hand

    full, up = problem.full, (0.0, 1.0, 0.0)
    hand = posed_hand(full, np.asarray(full.faces), np.asarray(full.bone_ids), v, j, sd)
    scenes, results = {}, {}
    for mass, grip in variants:
        if mass not in scenes:
            scenes[mass] = hand_scene([hand], problem.mesh, None, up, C.DEFAULT_DENSITY * mass)
        results[mass, grip] = hold(scenes[mass], up, grip=grip)[0]
    r = results[variants[0]]
    return dict(held=bool(r.held), displacement_mm=1e3 * r.displacement,
                rotation_deg=float(r.rotation), settle_mm=1e3 * r.settle,
                wedge=float(r.wedge), ruled_out=bool(r.ruled_out), diverged=bool(r.diverged),
                held_at={variant_name(*k): bool(x.held) for k, x in results.items()})


def load(data: Path, name: str):
    """An object's contact mesh recentred on its box centre, its field and synthesizer."""
    import trimesh

    from grip_bench.data.synth import grasp as G
    from grip_bench.data.synth.objects import FAMILIES
    from grip_bench.geometry.distance import DistanceField

    mesh = trimesh.load(data / "tools/object_meshes/contact_meshes" / f"{name}.ply",
                        process=False)
    mesh.vertices = mesh.vertices - mesh.bounding_box.centroid
    df = DistanceField(mesh)
    fam = FAMILIES.get(name.split("_")[0])
    gs = G.GraspSynthesizer(mesh, df, 1.0, rest_height=-float(mesh.bounds[0, 1]),
                            grasp_hint=fam.grasp_hint if fam else "power",
                            large=bool(fam.large) if fam else False)
    return mesh, df, gs


def probe_object(mesh, df, table_y: float, side: str, settings: Settings,
                 hold_test: bool = True,
                 variants: tuple[tuple[float, float], ...] = (DEFAULT_VARIANT,)) -> dict:
    """Optimise and judge one object: counts (``held_by_variant``: valid restarts held at
    each of ``variants``, :func:`judge`), time and one row per restart."""
    from grip_bench.core import constants as C
    from grip_bench.data.synth import grasp as G

    t0 = time.perf_counter()
    problem = Problem(mesh, df, side, table_y, C.DEFAULT_DENSITY)
    res = optimise(problem, settings)
    t_opt = time.perf_counter() - t0
    rows = judge(problem, res, hold_test, variants)
    held = [r for r in rows if r["held"]]
    by_variant = {variant_name(*k): sum(bool(r.get("held_at", {}).get(variant_name(*k)))
                                        for r in rows) for k in variants}
    fails = dict(deep=sum(r["depth_mm"] > 1e3 * G.MAX_PENETRATION for r in rows),
                 table=sum(r["low_mm"] < 1e3 * G.TABLE_CLEARANCE for r in rows),
                 no_touch=sum(not touching(r["touching"]) for r in rows))
    return dict(restarts=len(rows), valid=sum(r["valid"] for r in rows), valid_held=len(held),
                held_by_variant=by_variant,
                held_contacts=[r["touching"] for r in held], fails=fails,
                weight_n=problem.weight, optimise_s=t_opt,
                seconds=time.perf_counter() - t0, rows=rows)


def main(argv: list[str] | None = None) -> int:
    import torch

    from tools import probe_cli

    def extend(ap):
        ap.add_argument("--objects", nargs="+", default=list(OBJECTS))
        ap.add_argument("--side", default="right", choices=("right", "left"))
        ap.add_argument("--restarts", type=int, default=Settings.restarts)
        ap.add_argument("--steps", type=int, default=Settings.steps)
        ap.add_argument("--seed", type=int, default=Settings.seed)
        ap.add_argument("--mass-factors", type=float, nargs="+", default=[1.0],
                        help="hold each valid grasp with the object this many times as heavy")
        ap.add_argument("--grips", type=float, nargs="+", default=[1.0],
                        help="... and with the finger servos this many times as strong")

    args = probe_cli.parse(__doc__, argv, extend)
    torch.set_num_threads(1)
    settings = Settings(restarts=args.restarts, steps=args.steps, seed=args.seed)
    out = []
    for name in args.objects:
        mesh, df, gs = load(args.data, name)
        variants = tuple((m, g) for m in args.mass_factors for g in args.grips)
        res = {"object": name, **probe_object(mesh, df, gs.table_y, args.side, settings,
                                              variants=variants)}
        out.append(res)
        if not args.json:
            kinds = sorted({"+".join(c) for c in res["held_contacts"]})
            print(f"{name} ({res['weight_n']:.2f} N): {res['restarts']} restarts, "
                  f"{res['valid']} valid, {res['valid_held']} valid and held "
                  f"(contacts {', '.join(kinds) or '-'}); failing: {res['fails']['deep']} "
                  f"too deep, {res['fails']['table']} below the table, "
                  f"{res['fails']['no_touch']} without thumb + finger; "
                  f"{res['seconds']:.0f} s", flush=True)
            if len(variants) > 1:
                print("  valid and held at " + "; ".join(
                    f"{k}: {n}" for k, n in res["held_by_variant"].items()), flush=True)
    if args.json:
        print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    sys.exit(main())
