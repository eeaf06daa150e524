"""SynthGRAB's procedural object families: watertight household objects built with CSG.

Every family draws its parameters from realistic ranges (metres) and builds a closed
manifold with manifold3d (primitives, revolved 2D profiles, booleans, hulls, warps).
Builders work in a z-up *build frame* (manifold3d's native axis); `make_instance`
turns the result into the suite's object frame: **y up**, origin at the bounding-box
centre (GRAB meshes are centred), handles along +x where a family has one.
`rest_height` is the distance from the origin down to the lowest point, so an object
placed with its origin at `table_y + rest_height` stands on the table.

Public API
- `FAMILIES`: `Registry[ObjectFamily]`, ordered; `FAMILIES.get("mug")`.
- `make_instance(family_name, rng, index, variation=False) -> ObjectInstance`
- `make_object_set(seed, n_per_family=1, families=None, variation=True) -> list[ObjectInstance]`
- `reshape_instance(inst, stretch, lying=None) -> ObjectInstance`

Shape variation (SynthGRAB v2): besides its family parameters every generated instance is
stretched by its own non-uniform scale (`STRETCH_RANGE` per axis, then scaled as a whole
back into the family's size range), so apertures and finger closures vary continuously
within a family; round-sectioned objects without a use motion (`LYING_FAMILIES`) may lie
on their side. Both are drawn after the parameters, so the parameters of an instance are
those of the unvaried build.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np
import trimesh
from manifold3d import CrossSection, JoinType, Manifold, OpType

from ...core.constants import (
    SYNTH_LARGE_EXTENT,
    SYNTH_OBJ_SEGMENTS,
    SYNTH_OBJ_SEGMENTS_LARGE,
    SYNTH_OBJ_SEGMENTS_SMALL,
)
from ...core.errors import InputError
from ...core.registry import Registry

GRASP_HINTS = ("power", "precision", "tripod", "lateral", "bimanual", "handle")

SEG = SYNTH_OBJ_SEGMENTS
SEG_L = SYNTH_OBJ_SEGMENTS_LARGE
SEG_S = SYNTH_OBJ_SEGMENTS_SMALL

Params = dict[str, float]


# --------------------------------------------------------------------------- types


@dataclass(frozen=True)
class HandleRegion:
    """A graspable handle: centre point and unit axis along its length (object frame, m)."""

    name: str
    point: tuple[float, float, float]
    axis: tuple[float, float, float]
    length: float  # m, graspable length along `axis`
    thickness: float  # m, approximate cross-section diameter (grasp aperture)


@dataclass
class Built:
    """A builder's output in the z-up build frame."""

    solid: Manifold
    handles: list[HandleRegion] = field(default_factory=list)


@dataclass(frozen=True)
class ObjectFamily:
    """A procedural object family: parameter ranges, tags and a builder.

    `size_range` bounds the largest bounding-box extent of every instance (m).
    `params` maps a parameter name to its uniform draw range (m unless the name says).
    `volume` (optional) gives the analytic volume of an instance from its params (m^3).
    """

    name: str
    size_range: tuple[float, float]
    params: dict[str, tuple[float, float]]
    build: Callable[[Params], Built]
    grasp_hint: str
    use_motion: str
    large: bool = False
    volume: Callable[[Params], float] | None = None
    note: str = ""
    genus: int = 0  # handles through which a finger passes (mug 1, torus 1, pot 2)

    def sample(self, rng: np.random.Generator) -> Params:
        """Draw one parameter set, uniform within each range (sorted key order)."""
        return {k: float(rng.uniform(*self.params[k])) for k in sorted(self.params)}

    def describe(self) -> str:
        lo, hi = self.size_range
        big = ", large (two hands)" if self.large else ""
        size = f"{lo * 100:.0f}-{hi * 100:.0f} cm"
        return f"{self.note} [{size}, {self.grasp_hint}, {self.use_motion}{big}]"


@dataclass
class ObjectInstance:
    """One generated object: y-up mesh centred at its bounding-box centre (metres)."""

    name: str
    family: str
    mesh: trimesh.Trimesh
    params: Params
    grasp_hint: str
    use_motion: str
    large: bool
    rest_height: float  # m, origin to lowest point (along -y)
    handles: list[HandleRegion] = field(default_factory=list)
    stretch: tuple[float, float, float] = (1.0, 1.0, 1.0)  # object-frame scale of the build
    lying: bool = False  # turned onto its side (long axis along x) before stretching

    @property
    def tags(self) -> dict[str, object]:
        """The family tags as a plain dict (for manifests)."""
        return {"grasp_hint": self.grasp_hint, "use_motion": self.use_motion, "large": self.large}

    @property
    def shape(self) -> dict[str, object]:
        """The instance's shape variation as a plain dict (for manifests)."""
        return {"stretch": [round(float(x), 4) for x in self.stretch], "lying": self.lying,
                "extents_m": [round(float(x), 4) for x in self.mesh.extents]}


# ------------------------------------------------------------------ primitives


def _cyl_x(length: float, r: float, segs: int = SEG, r2: float | None = None) -> Manifold:
    """Cylinder (or cone to `r2`) along +x from x=0 to x=length."""
    top = r if r2 is None else r2
    return Manifold.cylinder(length, r, top, circular_segments=segs).rotate((0, 90, 0))


def _cyl_y(length: float, r: float, segs: int = SEG) -> Manifold:
    """Cylinder along y, centred at the origin."""
    return Manifold.cylinder(length, r, circular_segments=segs, center=True).rotate((90, 0, 0))


def _ellipsoid(radii: Sequence[float], centre: Sequence[float], segs: int = 24) -> Manifold:
    """Axis-aligned ellipsoid (geodesic sphere scaled)."""
    return Manifold.sphere(1.0, segs).scale(tuple(radii)).translate(tuple(centre))


def _hull(*parts: Manifold) -> Manifold:
    return Manifold.batch_hull(list(parts))


def _union(parts: Sequence[Manifold]) -> Manifold:
    return Manifold.batch_boolean(list(parts), OpType.Add)


def _rounded_box(size: Sequence[float], radius: float, segs: int = 12) -> Manifold:
    """Box of full `size` (x, y, z) centred at the origin, edges rounded by `radius`."""
    half = np.asarray(size, float) / 2 - radius
    ball = Manifold.sphere(radius, segs)
    corners = [ball.translate(tuple(half * s)) for s in _signs3()]
    return _hull(*corners)


def _signs3() -> list[np.ndarray]:
    return [np.array([a, b, c]) for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)]


def _capsule_chain(points: np.ndarray, radii: np.ndarray, segs: int = 16) -> Manifold:
    """Union of hulls of consecutive spheres: a tapered tube along a polyline.

    points (K, 3) m, radii (K,) m.
    """
    balls = [
        Manifold.sphere(float(r), segs).translate(tuple(p))
        for p, r in zip(points, radii, strict=True)
    ]
    return _union([_hull(a, b) for a, b in zip(balls[:-1], balls[1:], strict=True)])


def _torus_xz(
    major: float, minor: float, centre: Sequence[float], z_scale: float = 1.0
) -> Manifold:
    """Ring in the xz plane (hole along y), optionally stretched vertically (a D handle)."""
    circle = CrossSection.circle(minor, SEG_S).translate((major, 0.0))
    ring = Manifold.revolve(circle, SEG).rotate((90, 0, 0))
    return ring.scale((1.0, 1.0, z_scale)).translate(tuple(centre))


# --------------------------------------------------------------------- profiles


def _profile_section(outer: np.ndarray) -> CrossSection:
    """Mirror-symmetric 2D section from a right-half outline (r, z).

    outer (K, 2): the right half of the outline, from the axis at the bottom to the
    axis at the top; it is closed along the axis and made counter-clockwise.
    """
    pts = np.asarray(outer, float)
    area = 0.5 * np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1])
    right = CrossSection([pts if area > 0 else pts[::-1]])
    return right + right.mirror((1.0, 0.0))


def _revolve(section: CrossSection, segs: int = SEG) -> Manifold:
    """Revolve a 2D section (x = radius, y = height) about the build z axis."""
    return Manifold.revolve(section, segs)


def _band(section: CrossSection, z0: float, z1: float) -> CrossSection:
    """The part of `section` with z0 <= z <= z1."""
    box = CrossSection.square((10.0, z1 - z0)).translate((-5.0, z0))
    return section ^ box


def _cavity(section: CrossSection, wall: float, top: float, hollow_from: float) -> CrossSection:
    """Open-top cavity of a vessel section: the inset by `wall` plus a column above it.

    The column is the hull of the inset's top strip and a copy lifted far above, so the
    cavity breaks through the rim and leaves a wall `wall` thick.
    """
    inner = _band(section, hollow_from, top + 1.0).offset(-wall, JoinType.Miter, 2.0)
    strip = _band(inner, top - 2.5 * wall, top)
    return inner + (strip + strip.translate((0.0, 1.0))).hull()


def _vessel(
    outer: np.ndarray,
    wall: float,
    hollow_from: float = 0.0,
    segs: int = SEG,
    attach: Sequence[Manifold] = (),
) -> Manifold:
    """Hollow open-top solid of revolution with a rounded rim, plus attached handles.

    outer (K, 2): right-half outline (r, z) as in `_profile_section`, top at max z.
    Handles in `attach` are clipped by the cavity (shrunk by `_CLIP_GAP`, so no face
    of the clip coincides with the inner wall and the boolean leaves no slivers).
    """
    full = _profile_section(outer)
    top = float(np.max(np.asarray(outer)[:, 1]))
    cav = _cavity(full, wall, top, hollow_from)
    # Opening = erode then dilate: rounds the rim and outer corners, keeps the thickness.
    walls = (full - cav).offset(-0.4 * wall, JoinType.Round, 2.0, SEG_S)
    walls = walls.offset(0.4 * wall, JoinType.Round, 2.0, SEG_S).simplify(1e-5)
    body = _revolve(walls, segs)
    if not attach:
        return body
    clip = _revolve(cav.offset(-_CLIP_GAP, JoinType.Miter, 2.0).simplify(1e-5), segs)
    return body + (_union(list(attach)) - clip)


_CLIP_GAP = 2e-4  # m; handle stubs may stand 0.2 mm proud of the inner wall


def _arc(r0: float, r1: float, z0: float, z1: float, n: int) -> np.ndarray:
    """Quarter-ellipse from (r0, z0) bulging out to (r1, z1): a bowl-like side (n, 2)."""
    phi = np.linspace(0.0, np.pi / 2, n)
    return np.stack([r0 + (r1 - r0) * np.sin(phi), z0 + (z1 - z0) * (1 - np.cos(phi))], axis=1)


# ----------------------------------------------------------- simple primitives


def _sphere(p: Params) -> Built:
    return Built(Manifold.sphere(p["diameter"] / 2, SEG_L))


def _sphere_volume(p: Params) -> float:
    return np.pi * p["diameter"] ** 3 / 6


def _bin(p: Params) -> Built:
    """Open-top storage box: a floor and four walls ``wall`` thick (a container, so its mass
    is its walls': a solid block that size weighed 10.5 kg at the suite's density)."""
    sx, sy, sz, w = p["size_x"], p["size_y"], p["size_z"], p["wall"]
    outer = Manifold.cube((sx, sy, sz), center=True)
    inner = Manifold.cube((sx - 2 * w, sy - 2 * w, sz), center=True).translate((0, 0, w))
    return Built(outer - inner)


def _bin_volume(p: Params) -> float:
    sx, sy, sz, w = p["size_x"], p["size_y"], p["size_z"], p["wall"]
    return sx * sy * sz - (sx - 2 * w) * (sy - 2 * w) * (sz - w)


def _cube(p: Params) -> Built:
    return Built(Manifold.cube((p["edge"],) * 3, center=True))


def _cube_volume(p: Params) -> float:
    return p["edge"] ** 3


def _cylinder(p: Params) -> Built:
    return Built(
        Manifold.cylinder(p["height"], p["diameter"] / 2, circular_segments=SEG, center=True)
    )


def _cylinder_volume(p: Params) -> float:
    return np.pi * (p["diameter"] / 2) ** 2 * p["height"]


def _torus(p: Params) -> Built:
    circle = CrossSection.circle(p["tube_radius"], 24).translate((p["ring_radius"], 0.0))
    return Built(Manifold.revolve(circle, SEG_L))


def _torus_volume(p: Params) -> float:
    return 2 * np.pi**2 * p["ring_radius"] * p["tube_radius"] ** 2


# ---------------------------------------------------------------------- vessels


def _mug(p: Params) -> Built:
    """Cylindrical mug, open top, wall `wall`, D-shaped loop handle on +x.

    `with_handle = 0` (not a drawn parameter) builds the body alone, for volume checks.
    """
    r, h, w = p["radius"], p["height"], p["wall"]
    outer = np.array([[0, 0], [r, 0], [r, h], [0, h]])
    if p.get("with_handle", 1.0) < 0.5:
        return Built(_vessel(outer, w))
    major, minor, zc = 0.3 * h / 1.3, p["handle_tube"], 0.52 * h
    ring = _torus_xz(major, minor, (r + 0.2 * major, 0, zc), z_scale=1.3)
    grip = HandleRegion(
        "handle", (r + 1.2 * major, 0.0, zc), (0.0, 0.0, 1.0), 1.6 * major, 2 * minor
    )
    return Built(_vessel(outer, w, attach=[ring]), [grip])


def mug_body_volume(p: Params) -> float:
    """Analytic volume of a mug without its handle (m^3): outer cylinder minus cavity.

    The cavity has radius `radius - wall` and its floor at z = `wall`; the rounded rim
    changes this by < 0.1%.
    """
    r, h, w = p["radius"], p["height"], p["wall"]
    return np.pi * (r**2 * h - (r - w) ** 2 * (h - w))


def _cup(p: Params) -> Built:
    """Tapered cup without a handle (GRAB `cup`)."""
    rt, h = p["radius"], p["height"]
    rb = rt * p["taper"]
    outer = np.array([[0, 0], [rb, 0], [rt, h], [0, h]])
    return Built(_vessel(outer, p["wall"]))


def _bowl_outline(r_rim: float, h: float, base_frac: float, n: int = 12) -> np.ndarray:
    side = _arc(r_rim * base_frac, r_rim, 0.0, h, n)
    return np.vstack([[0.0, 0.0], side, [0.0, h]])


def _bowl(p: Params) -> Built:
    """Round bowl on a flat base (also the large basin)."""
    outer = _bowl_outline(p["diameter"] / 2, p["height"], 0.45)
    return Built(_vessel(outer, p["wall"], segs=SEG_L))


def _wineglass(p: Params) -> Built:
    """Foot, stem and a tulip bowl hollowed from the stem top up."""
    rf, rs, hs, rb, hb = (
        p["foot_radius"],
        p["stem_radius"],
        p["stem_height"],
        p["bowl_radius"],
        p["bowl_height"],
    )
    t = np.linspace(0, 1, 14)[1:]
    bowl_r = rb * np.sin(np.pi * (0.1 + 0.55 * t)) ** 0.6 + rs * (1 - t) ** 4
    bowl_z = hs + hb * t
    foot = [[0, 0], [rf, 0], [rf, 0.003], [rs * 1.8, 0.008], [rs, 0.016], [rs, hs - 0.004]]
    outer = np.vstack([foot, np.stack([bowl_r, bowl_z], 1), [[0, hs + hb]]])
    return Built(_vessel(outer, p["wall"], hollow_from=hs + 0.004))


def _fryingpan(p: Params) -> Built:
    """Shallow flared pan with a long, slightly rising handle along +x."""
    r, h, w = p["diameter"] / 2, p["height"], p["wall"]
    side = _arc(0.78 * r, r, 0.0, h, 6)
    outer = np.vstack([[0, 0], side, [0, h]])
    length, rise = p["handle_length"], np.tan(np.radians(12.0))
    z0 = 0.65 * h
    start = (r - 0.006, 0.0, z0)
    end = (r + length, 0.0, z0 + length * rise)
    handle = _hull(
        _ellipsoid((0.01, 0.011, 0.007), start, 16), _ellipsoid((0.014, 0.014, 0.008), end, 16)
    )
    axis = np.array([1.0, 0.0, rise]) / np.hypot(1.0, rise)
    mid = tuple(np.add(start, end) / 2 + axis * 0.25 * length)
    grip = HandleRegion("handle", mid, tuple(axis), 0.5 * length, 0.018)
    return Built(_vessel(outer, w, segs=SEG_L, attach=[handle]), [grip])


def _pot(p: Params) -> Built:
    """Large cooking pot: open cylinder with two loop handles at +-x near the rim."""
    r, h, w = p["diameter"] / 2, p["height"], p["wall"]
    outer = np.array([[0, 0], [r, 0], [r, h], [0, h]])
    major, minor, zc = 0.03, 0.0075, h - 0.03
    loop = CrossSection.circle(minor, SEG_S).translate((major, 0.0))
    rings, grips = [], []
    for s, name in ((1.0, "handle_right"), (-1.0, "handle_left")):
        # Horizontal side loops, stretched along y so four fingers fit through.
        ring = Manifold.revolve(loop, SEG).scale((0.8, 1.4, 1.0))
        rings.append(ring.translate((s * (r + 0.2 * major), 0, zc)))
        grips.append(
            HandleRegion(name, (s * (r + major), 0.0, zc), (0.0, 1.0, 0.0), 0.07, 2 * minor)
        )
    return Built(_vessel(outer, w, segs=SEG_L, attach=rings), grips)


# ------------------------------------------------------------ revolved solids


def _waterbottle(p: Params) -> Built:
    """Closed bottle: body, rounded shoulder, neck and cap."""
    r, h = p["diameter"] / 2, p["height"]
    rn, cap_h = 0.4 * r + 0.004, 0.022
    zs = h - cap_h - 0.02 - 0.06 * h  # shoulder start
    phi = np.linspace(0, np.pi / 2, 7)  # quarter-ellipse from the body into the neck
    shoulder = np.stack(
        [rn + (r - rn) * np.cos(phi), zs + (h - cap_h - 0.018 - zs) * np.sin(phi)], 1
    )
    outer = np.vstack(
        [
            [[0, 0], [r - 0.004, 0], [r, 0.004]],
            shoulder,
            [[rn, h - cap_h], [rn + 0.002, h - cap_h], [rn + 0.002, h - 0.002], [rn, h], [0, h]],
        ]
    )
    return Built(_revolve(_profile_section(outer)))


def _apple(p: Params) -> Built:
    """Slightly flattened sphere with dimples at both poles and a short stem."""
    rad = p["diameter"] / 2
    phi = np.linspace(0.0, np.pi, 25)
    rho = rad * (
        1 - 0.14 * np.exp(-(((np.pi - phi) / 0.45) ** 2)) - 0.07 * np.exp(-((phi / 0.4) ** 2))
    )
    pts = np.stack([rho * np.sin(phi) * 1.04, -rho * np.cos(phi) * 0.9], axis=1)
    pts[0, 0] = pts[-1, 0] = 0.0
    body = _revolve(_profile_section(pts))
    top = float(pts[-1, 1])
    stem = Manifold.cylinder(0.016, 0.0022, 0.0016, circular_segments=SEG_S)
    stem = stem.rotate((12, 0, 0)).translate((0, 0, top - 0.004))
    return Built(body + stem)


# ---------------------------------------------------------------- elongated


def _banana(p: Params) -> Built:
    """A tapered five-sided tube bent along an arc in the horizontal plane."""
    length, r0, bend = p["length"], p["diameter"] / 2, p["bend_rad"]
    ang = np.linspace(0, 2 * np.pi, 20, endpoint=False)
    rim = 1 + 0.06 * np.cos(5 * ang)
    ring = CrossSection([np.stack([rim * np.cos(ang), rim * np.sin(ang)], 1)])
    tube = Manifold.extrude(ring, 1.0, n_divisions=28)
    arc_len = length * (bend / 2) / np.sin(bend / 2)  # chord = length
    rc = arc_len / bend

    def warp(v: np.ndarray) -> np.ndarray:
        t = v[:, 2]
        rad = r0 * np.maximum(np.sin(np.pi * t), 0.0) ** 0.55 * 0.82 + 0.18 * r0
        theta = bend * (t - 0.5)
        # (norm, z, tangent) is right-handed, so the warp keeps the normals outward.
        norm = np.stack([-np.sin(theta), np.cos(theta)], 1)
        centre = rc * np.stack([np.sin(theta), 1 - np.cos(theta)], 1)
        xy = centre + (rad * v[:, 0])[:, None] * norm
        return np.column_stack([xy, rad * v[:, 1]])

    theta0 = -bend / 2  # the stem end (t = 0): extend it backwards along the tangent
    end = rc * np.array([np.sin(theta0), 1 - np.cos(theta0), 0.0])
    back = -np.array([np.cos(theta0), np.sin(theta0), 0.0])
    stem = _capsule_chain(
        np.stack([end - 0.002 * back, end + 0.014 * back]), np.array([0.2, 0.16]) * r0, 10
    )
    return Built(tube.warp_batch(warp) + stem)


def _toothpaste(p: Params) -> Built:
    """Tube lying along x: round at the cap end, crimped flat at the far end."""
    r, length = p["diameter"] / 2, p["length"]
    disc = _cyl_x(0.002, r)
    flat = Manifold.cube((0.003, 2.8 * r, 0.003), center=True).translate((length, 0, 0))
    tube = _hull(disc, flat)
    seal = Manifold.cube((0.012, 2.8 * r, 0.0026), center=True).translate((length + 0.005, 0, 0))
    shoulder = _cyl_x(0.008, 0.45 * r, SEG, r).translate((-0.008, 0, 0))
    # The cap overlaps the shoulder by 1 mm so the union is one body, not two touching.
    cap = _cyl_x(p["cap_length"], 0.5 * r, SEG).translate((-0.007 - p["cap_length"], 0, 0))
    return Built(_union([tube, seal, shoulder, cap]))


def _toothbrush(p: Params) -> Built:
    """Handle, thin neck, flat head with a bristle block on top (+z)."""
    length = p["length"]
    x_head = length - 0.03
    handle = _hull(
        _ellipsoid((0.012, 0.009, 0.007), (0.012, 0, 0), 16),
        _ellipsoid((0.02, 0.0075, 0.0055), (0.6 * length, 0, 0), 16),
    )
    neck = _hull(
        _ellipsoid((0.01, 0.005, 0.004), (0.6 * length, 0, 0), 12),
        _ellipsoid((0.006, 0.0045, 0.0032), (x_head, 0, 0), 12),
    )
    head = _rounded_box((0.03, 0.013, 0.006), 0.0025).translate((x_head + 0.013, 0, 0))
    bristles = Manifold.cube((0.024, 0.010, p["bristle_height"]), center=True)
    bristles = bristles.translate((x_head + 0.013, 0, 0.0025 + p["bristle_height"] / 2))
    grip = HandleRegion("handle", (0.3 * length, 0.0, 0.0), (1.0, 0.0, 0.0), 0.5 * length, 0.016)
    return Built(_union([handle, neck, head, bristles]), [grip])


def _knife(p: Params) -> Built:
    """Kitchen knife lying flat: blade in the horizontal plane, handle along +x."""
    lb, wb, lh, tb = p["blade_length"], p["blade_width"], p["handle_length"], p["blade_thickness"]
    edge_x = np.linspace(0.55, 1.0, 7)
    edge_y = -wb / 2 + (wb * 0.85) * ((edge_x - 0.55) / 0.45) ** 2
    outline = np.vstack(
        [[[0.0, -wb / 2]], np.stack([edge_x * lb, edge_y], 1), [[0.75 * lb, wb / 2], [0.0, wb / 2]]]
    )
    # Blade points to -x so the handle sits on +x like every other handle.
    blade = (
        Manifold.extrude(CrossSection([outline]), tb).translate((0, 0, -tb / 2)).mirror((1, 0, 0))
    )
    bolster = _ellipsoid((0.006, wb / 2 + 0.001, 0.008), (0.004, 0, 0), 16)
    handle = _hull(
        _ellipsoid((0.01, 0.01, 0.008), (0.01, 0, 0), 16),
        _ellipsoid((0.012, 0.0125, 0.01), (lh - 0.012, 0, 0), 16),
    )
    grip = HandleRegion("handle", (lh / 2, 0.0, 0.0), (1.0, 0.0, 0.0), lh, 0.022)
    return Built(_union([blade, bolster, handle]), [grip])


def _flute(p: Params) -> Built:
    """Closed rod with joint rings, an embouchure hole and six finger holes on top."""
    r, length = p["diameter"] / 2, p["length"]
    body = _cyl_x(length, r)
    rings = [
        _cyl_x(0.012, r * 1.12).translate((x, 0, 0)) for x in (0.0, 0.3 * length, length - 0.012)
    ]
    holes = [
        Manifold.cylinder(0.01, 0.0035, circular_segments=SEG_S).translate(
            (x * length, 0, r - 0.003)
        )
        for x in (0.5, 0.56, 0.62, 0.72, 0.78, 0.84)
    ]
    embouchure = Manifold.cylinder(0.01, 1.0, circular_segments=SEG_S).scale((0.006, 0.0045, 1))
    embouchure = embouchure.translate((0.1 * length, 0, r - 0.003))
    return Built(_union([body, *rings]) - _union([*holes, embouchure]))


# --------------------------------------------------------------- composites


def _camera(p: Params) -> Built:
    """Compact camera: rounded body, lens barrel on the front (-y), viewfinder, button."""
    w, d, h, rl, ll = p["width"], p["depth"], p["height"], p["lens_radius"], p["lens_length"]
    body = _rounded_box((w, d, h), 0.006)
    lens_x = -0.08 * w
    lens = _cyl_y(ll + 0.01, rl).translate((lens_x, -d / 2 - ll / 2 + 0.005, 0.0))
    ring = _cyl_y(0.006, rl * 1.1).translate((lens_x, -d / 2 - 0.002, 0.0))
    glass = _cyl_y(0.004, rl * 0.75).translate((lens_x, -d / 2 - ll - 0.001, 0.0))
    hump = _rounded_box((0.4 * rl + 0.02, 0.7 * d, 0.02), 0.004).translate(
        (lens_x, 0.05 * d, h / 2)
    )
    button = Manifold.cylinder(0.006, 0.005, circular_segments=SEG_S).translate(
        (0.32 * w, -0.1 * d, h / 2 - 0.001)
    )
    grip = _ellipsoid((0.012, 0.009, 0.42 * h), (0.38 * w, -d / 2, 0.0), 16)
    return Built(_union([body, lens, ring, glass, hump, button, grip]))


def _binoculars(p: Params) -> Built:
    """Two stepped barrels along y (lying flat), a central hinge and a focus wheel."""
    length, ro, sep = p["length"], p["barrel_radius"], p["separation"]
    re = 0.62 * ro
    parts = []
    for s in (-1.0, 1.0):
        x = s * sep / 2
        parts.append(_cyl_y(0.6 * length, ro).translate((x, -0.2 * length, 0)))
        parts.append(_cyl_y(0.25 * length, re).translate((x, 0.375 * length, 0)))
        # Prism housing tapers from the objective tube into the eyepiece tube.
        taper = Manifold.cylinder(0.15 * length + 0.002, ro, re, circular_segments=SEG).rotate(
            (-90, 0, 0)
        )
        parts.append(taper.translate((x, 0.1 * length - 0.001, 0)))
        parts.append(_cyl_y(0.012, ro * 1.06).translate((x, -0.5 * length + 0.006, 0)))
    bridge = Manifold.cube((sep, 0.35 * length, 0.9 * ro), center=True).translate(
        (0, -0.05 * length, 0)
    )
    hinge = _cyl_y(0.55 * length, 0.55 * ro).translate((0, -0.05 * length, 0))
    wheel = _cyl_y(0.018, 0.4 * ro, SEG).translate((0, 0.2 * length, 0.5 * ro))
    return Built(_union([*parts, bridge, hinge, wheel]))


def _elephant(p: Params) -> Built:
    """Toy elephant standing on four legs: body, head, ears, curled trunk, tail."""
    length = p["length"]
    s = length / 1.45  # body length unit; trunk and tail add the rest
    hgt, wid = p["height_ratio"] * s, p["width_ratio"] * s
    leg_h = 0.35 * hgt
    bz = leg_h + 0.28 * hgt
    body = _ellipsoid((0.5 * s, wid / 2, 0.33 * hgt), (0, 0, bz), 32)
    legs = [
        Manifold.cylinder(bz, 0.09 * s, 0.1 * s, circular_segments=SEG_S + 4).translate(
            (x * s, y * wid, 0)
        )
        for x in (-0.3, 0.28)
        for y in (-0.28, 0.28)
    ]
    hx, hz, hr = 0.55 * s, bz + 0.28 * hgt, 0.24 * hgt
    head = _ellipsoid((hr, 0.9 * hr, hr), (hx, 0, hz), 28)
    ears = [
        _ellipsoid((0.025 * s, 0.2 * s, 0.26 * hgt), (hx - 0.2 * hr, y * 0.75 * hr, hz), 20)
        for y in (-1, 1)
    ]
    u = np.linspace(0, 1, 7)
    trunk_pts = np.stack(
        [
            hx + hr * 0.8 + 0.1 * s * np.sin(np.pi * u * 0.9),
            np.zeros_like(u),
            hz - 0.1 * hgt - (hz - 0.1 * hgt - 0.12 * hgt) * u**1.2,
        ],
        1,
    )
    trunk = _capsule_chain(trunk_pts, 0.07 * s * (1 - 0.55 * u) + 0.004, 14)
    tail = _capsule_chain(
        np.array([[-0.48 * s, 0, bz + 0.1 * hgt], [-0.6 * s, 0, bz - 0.15 * hgt]]),
        np.array([0.02 * s, 0.012 * s]),
        10,
    )
    return Built(_union([body, *legs, head, *ears, trunk, tail]))


# -------------------------------------------------------------------- registry

_W = (0.003, 0.005)  # vessel wall thickness range (m): real cups are 3-5 mm


def _fam(
    name: str,
    size: tuple[float, float],
    params: dict[str, tuple[float, float]],
    build: Callable[[Params], Built],
    hint: str,
    use: str,
    large: bool = False,
    volume: Callable[[Params], float] | None = None,
    note: str = "",
    genus: int = 0,
) -> ObjectFamily:
    return ObjectFamily(name, size, params, build, hint, use, large, volume, note, genus)


def _families() -> list[ObjectFamily]:
    """The family table: name, largest-extent range (m), parameter ranges, builder, tags."""
    lo_l, hi_l = SYNTH_LARGE_EXTENT
    # fmt: off
    return [
        _fam("spheresmall", (0.039, 0.051), {"diameter": (0.04, 0.05)},
             _sphere, "tripod", "none", volume=_sphere_volume, note="small ball"),
        _fam("spheremedium", (0.059, 0.071), {"diameter": (0.06, 0.07)},
             _sphere, "power", "none", volume=_sphere_volume, note="medium ball"),
        _fam("spherelarge", (0.089, 0.111), {"diameter": (0.09, 0.11)},
             _sphere, "power", "none", volume=_sphere_volume, note="large ball"),
        _fam("cubesmall", (0.035, 0.045), {"edge": (0.035, 0.045)},
             _cube, "precision", "none", volume=_cube_volume, note="small cube"),
        _fam("cubemedium", (0.055, 0.065), {"edge": (0.055, 0.065)},
             _cube, "power", "none", volume=_cube_volume, note="medium cube"),
        _fam("cubelarge", (0.085, 0.1), {"edge": (0.085, 0.1)},
             _cube, "power", "none", volume=_cube_volume, note="large cube"),
        _fam("cylindersmall", (0.07, 0.09), {"diameter": (0.025, 0.032), "height": (0.07, 0.09)},
             _cylinder, "precision", "none", volume=_cylinder_volume, note="small cylinder"),
        _fam("cylindermedium", (0.09, 0.11), {"diameter": (0.045, 0.055), "height": (0.09, 0.11)},
             _cylinder, "power", "none", volume=_cylinder_volume, note="medium cylinder"),
        _fam("cylinderlarge", (0.11, 0.13), {"diameter": (0.07, 0.085), "height": (0.11, 0.13)},
             _cylinder, "power", "none", volume=_cylinder_volume, note="large cylinder"),
        _fam("can", (0.11, 0.125), {"diameter": (0.062, 0.068), "height": (0.11, 0.125)},
             _cylinder, "power", "drink", volume=_cylinder_volume, note="drink can"),
        _fam("torussmall", (0.06, 0.08),
             {"ring_radius": (0.023, 0.03), "tube_radius": (0.007, 0.01)},
             _torus, "precision", "none", volume=_torus_volume, genus=1, note="small ring"),
        _fam("torusmedium", (0.09, 0.12),
             {"ring_radius": (0.035, 0.047), "tube_radius": (0.01, 0.013)},
             _torus, "power", "none", volume=_torus_volume, genus=1, note="donut-sized ring"),
        _fam("toruslarge", (0.13, 0.17),
             {"ring_radius": (0.052, 0.068), "tube_radius": (0.013, 0.017)},
             _torus, "power", "none", volume=_torus_volume, genus=1, note="large ring"),
        _fam("apple", (0.065, 0.092), {"diameter": (0.068, 0.085)},
             _apple, "power", "eat", note="apple"),
        _fam("banana", (0.15, 0.23),
             {"length": (0.15, 0.2), "diameter": (0.03, 0.037), "bend_rad": (0.8, 1.2)},
             _banana, "power", "eat", note="bent tapered tube"),
        _fam("mug", (0.105, 0.14),
             {"radius": (0.038, 0.045), "height": (0.085, 0.105), "wall": _W,
              "handle_tube": (0.005, 0.0065)},
             _mug, "handle", "drink", genus=1, note="hollow mug with loop handle"),
        _fam("cup", (0.085, 0.115),
             {"radius": (0.035, 0.042), "height": (0.085, 0.11), "wall": _W, "taper": (0.72, 0.85)},
             _cup, "power", "drink", note="tapered cup"),
        _fam("wineglass", (0.15, 0.21),
             {"foot_radius": (0.03, 0.037), "stem_radius": (0.0035, 0.0045),
              "stem_height": (0.07, 0.09), "bowl_radius": (0.036, 0.045),
              "bowl_height": (0.085, 0.11), "wall": (0.0025, 0.003)},
             _wineglass, "precision", "drink", note="revolved stemmed glass"),
        _fam("waterbottle", (0.2, 0.26), {"diameter": (0.06, 0.075), "height": (0.2, 0.26)},
             _waterbottle, "power", "pour", note="closed bottle with cap"),
        _fam("bowl", (0.14, 0.18), {"diameter": (0.14, 0.18), "height": (0.05, 0.07), "wall": _W},
             _bowl, "power", "drink", note="hollow bowl"),
        _fam("fryingpan", (0.29, 0.42),
             {"diameter": (0.17, 0.22), "height": (0.035, 0.05), "wall": _W,
              "handle_length": (0.14, 0.19)},
             _fryingpan, "handle", "cook", note="shallow pan with long handle"),
        _fam("knife", (0.21, 0.31),
             {"blade_length": (0.11, 0.18), "blade_width": (0.022, 0.032),
              "handle_length": (0.1, 0.13), "blade_thickness": (0.0022, 0.003)},
             _knife, "handle", "cut", note="kitchen knife"),
        _fam("toothbrush", (0.16, 0.2),
             {"length": (0.165, 0.195), "bristle_height": (0.008, 0.011)},
             _toothbrush, "precision", "brush", note="toothbrush"),
        _fam("toothpaste", (0.16, 0.23),
             {"diameter": (0.028, 0.036), "length": (0.13, 0.18), "cap_length": (0.012, 0.02)},
             _toothpaste, "power", "squeeze", note="crimped tube with cap"),
        _fam("flute", (0.26, 0.34), {"diameter": (0.018, 0.024), "length": (0.26, 0.34)},
             _flute, "precision", "play", note="rod with holes"),
        _fam("camera", (0.105, 0.14),
             {"width": (0.105, 0.13), "depth": (0.035, 0.045), "height": (0.065, 0.08),
              "lens_radius": (0.02, 0.028), "lens_length": (0.02, 0.04)},
             _camera, "power", "look", note="compact camera"),
        _fam("binoculars", (0.11, 0.16),
             {"length": (0.11, 0.15), "barrel_radius": (0.02, 0.026), "separation": (0.062, 0.075)},
             _binoculars, "power", "look", note="two barrels and a hinge"),
        _fam("elephant", (0.12, 0.2),
             {"length": (0.12, 0.19), "height_ratio": (0.85, 1.0), "width_ratio": (0.5, 0.6)},
             _elephant, "power", "none", note="toy elephant"),
        _fam("boxlarge", (lo_l, 0.45),
             {"size_x": (0.3, 0.45), "size_y": (0.2, 0.3), "size_z": (0.18, 0.28),
              "wall": (0.004, 0.006)},
             _bin, "bimanual", "none", large=True, volume=_bin_volume,
             note="open storage box"),
        _fam("basin", (0.31, hi_l),
             {"diameter": (0.32, 0.45), "height": (0.1, 0.16), "wall": (0.004, 0.005)},
             _bowl, "bimanual", "pour", large=True, note="large hollow basin"),
        _fam("balllarge", (lo_l, 0.4), {"diameter": (0.3, 0.4)},
             _sphere, "bimanual", "none", large=True, volume=_sphere_volume, note="big ball"),
        _fam("pot", (lo_l, 0.42),
             {"diameter": (0.24, 0.32), "height": (0.14, 0.2), "wall": (0.004, 0.005)},
             _pot, "bimanual", "pour", large=True, genus=2, note="pot with two handles"),
    ]
    # fmt: on


FAMILIES: Registry[ObjectFamily] = Registry("object family")
for _f in _families():
    FAMILIES.register(_f.name, _f)


# ------------------------------------------------------------------- instances


def _to_y_up(v: np.ndarray) -> np.ndarray:
    """Build frame (z up) -> object frame (y up): (x, y, z) -> (x, z, -y), a rotation."""
    v = np.asarray(v, float)
    return np.stack([v[..., 0], v[..., 2], -v[..., 1]], axis=-1)


def _to_trimesh(solid: Manifold) -> trimesh.Trimesh:
    """Manifold -> float64 Trimesh in the y-up frame (not yet centred)."""
    if solid.status().name != "NoError" or solid.is_empty():
        raise RuntimeError(f"CSG failed: {solid.status()}")
    mesh = solid.to_mesh64()
    verts = _to_y_up(np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3])
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    mesh = trimesh.Trimesh(verts, faces, process=False)
    # A bare revolve keeps its two pole vertices twice; the spares are unreferenced.
    mesh.remove_unreferenced_vertices()
    return mesh


def _move_handle(h: HandleRegion, offset: np.ndarray) -> HandleRegion:
    point = tuple(float(x) for x in _to_y_up(h.point) - offset)
    axis = tuple(float(x) for x in _to_y_up(h.axis))
    return HandleRegion(h.name, point, axis, h.length, h.thickness)


def instance_name(family_name: str, index: int) -> str:
    """GRAB-like instance name: `mug` for index 0, then `mug_2`, `mug_3`..."""
    return family_name if index == 0 else f"{family_name}_{index + 1}"


# Per-axis stretch of a varied instance: a factor exp(u), u uniform in +-log(1.25), so
# proportions change by up to ~1.25 per axis and ~1.55 between two axes (then the whole is
# scaled back into the family's size range).
STRETCH_RANGE = (1 / 1.25, 1.25)
# Families whose instances may lie on their side (round section, no use motion that needs
# them upright), and how often.
LYING_FAMILIES = ("cylindersmall", "cylindermedium", "cylinderlarge")
LYING_PROBABILITY = 0.4


def make_instance(
    family_name: str, rng: np.random.Generator, index: int = 0, variation: bool = False
) -> ObjectInstance:
    """Draw and build one instance of a family.

    variation: also draw the instance's stretch and (for `LYING_FAMILIES`) whether it lies
    on its side (after the parameters, from the same stream; see the module docstring).
    Returns an `ObjectInstance` whose mesh is float64 metres, y up, centred at its
    bounding-box centre, watertight with outward normals.
    """
    fam = FAMILIES.get(family_name)
    params = fam.sample(rng)
    built = fam.build(params)
    mesh = _to_trimesh(built.solid)
    lo, hi = mesh.bounds
    centre = (lo + hi) / 2
    mesh.vertices = mesh.vertices - centre
    inst = ObjectInstance(
        name=instance_name(family_name, index),
        family=family_name,
        mesh=mesh,
        params=params,
        grasp_hint=fam.grasp_hint,
        use_motion=fam.use_motion,
        large=fam.large,
        rest_height=float(centre[1] - lo[1]),
        handles=[_move_handle(h, centre) for h in built.handles],
    )
    if not variation:
        return inst
    lo_s, hi_s = np.log(STRETCH_RANGE)
    stretch = np.exp(rng.uniform(lo_s, hi_s, size=3))
    lying = family_name in LYING_FAMILIES and bool(rng.random() < LYING_PROBABILITY)
    return reshape_instance(inst, stretch, lying=lying, size_range=fam.size_range)


_LIE = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # +y -> -x: a quarter turn


def reshape_instance(
    inst: ObjectInstance,
    stretch: Sequence[float],
    lying: bool | None = None,
    size_range: tuple[float, float] | None = None,
) -> ObjectInstance:
    """The instance stretched by `stretch` (3,) along the object axes (after turning it onto
    its side when `lying`), re-centred, with its handles and rest height following.

    size_range (m): when given, the stretched object is scaled as a whole so that its
    largest extent stays within it (the stored stretch includes that scale).
    A stretch of a stretched instance multiplies; `lying` given for an already lying
    instance turns nothing again. Used by the generator and to make same-family variants
    of one instance (different size or proportions, the same build).
    """
    S = np.asarray(stretch, float).reshape(3)
    if not (np.isfinite(S).all() and (S > 0).all()):
        raise InputError(f"stretch factors must be positive, got {S.tolist()}", "stretch")
    turn = bool(lying) and not inst.lying
    v = np.asarray(inst.mesh.vertices, float)
    R = _LIE if turn else np.eye(3)
    v = v @ R.T
    ext = (v.max(0) - v.min(0)) * S
    if size_range is not None:
        big = float(ext.max())
        lo_r, hi_r = size_range  # (a hair inside, so that rounding keeps it within)
        S = S * float(np.clip(big, lo_r * (1 + 1e-9), hi_r * (1 - 1e-9))) / big
    v = v * S
    lo, hi = v.min(0), v.max(0)
    centre = (lo + hi) / 2
    mesh = trimesh.Trimesh(v - centre, np.asarray(inst.mesh.faces), process=False)
    handles = []
    for h in inst.handles:
        axis = S * (R @ np.asarray(h.axis, float))
        k = float(np.linalg.norm(axis))
        across = np.delete(S, int(np.argmax(np.abs(R @ np.asarray(h.axis, float)))))
        handles.append(HandleRegion(
            h.name, tuple(float(x) for x in S * (R @ np.asarray(h.point, float)) - centre),
            tuple(float(x) for x in axis / k), h.length * k, h.thickness * float(across.mean())))
    prev = np.asarray(inst.stretch, float)
    total = S * (prev[np.abs(R).argmax(1)] if turn else prev)
    return ObjectInstance(
        name=inst.name, family=inst.family, mesh=mesh, params=inst.params,
        grasp_hint=inst.grasp_hint, use_motion=inst.use_motion, large=inst.large,
        rest_height=float(-lo[1] + centre[1]), handles=handles,
        stretch=tuple(float(x) for x in total), lying=inst.lying or turn,
    )


def _instance_rng(seed: int, family_name: str, index: int) -> np.random.Generator:
    """Independent stream per (seed, family, index): adding a family changes no other."""
    return np.random.default_rng([int(seed), zlib.crc32(family_name.encode()), int(index)])


def make_object_set(
    seed: int,
    n_per_family: int = 1,
    families: Sequence[str] | None = None,
    variation: bool = True,
) -> list[ObjectInstance]:
    """Build `n_per_family` instances of each family (all by default), deterministic in `seed`.

    variation: each instance with its own stretch (and side) as SynthGRAB v2 generates them;
    False builds the unvaried family instances (SynthGRAB v1's objects).
    """
    names = list(families) if families is not None else FAMILIES.names()
    return [
        make_instance(name, _instance_rng(seed, name, i), i, variation=variation)
        for name in names
        for i in range(n_per_family)
    ]
