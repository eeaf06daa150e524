"""The side-by-side video renderer (grip_bench/report/video.py): the z-buffer rasterizer against
analytic cases and a naive per-pixel reference, the camera fit, the colours, and the MP4 / GIF
encoders (decodable, right frame count and size, byte-stable)."""

from __future__ import annotations

import numpy as np
import pytest

from grip_bench.core.errors import InputError
from grip_bench.report import video as V

RED, BLUE = (255, 0, 0), (0, 0, 255)


def _covered(image: np.ndarray) -> np.ndarray:
    return (image != np.asarray(V.BACKGROUND, np.uint8)).any(axis=-1)


def _square(x0, y0, x1, y1, z):
    """Two triangles covering [x0, x1] x [y0, y1] at depth z: vertices (4, 3), faces (2, 3)."""
    v = np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z], [x0, y1, z]], float)
    return v, np.array([[0, 1, 2], [0, 2, 3]])


def naive_rasterize(screen, faces, rgb, width, height):
    """Per pixel, per triangle: barycentrics by solving a 2x2 system, nearest true depth wins."""
    image = np.zeros((height, width, 3), np.uint8)
    image[:] = V.BACKGROUND
    depth = np.full((height, width), np.inf)
    for j in range(height):
        for i in range(width):
            p = np.array([i + 0.5, j + 0.5])
            for f, (a, b, c) in enumerate(faces):
                A, B, Cc = screen[a], screen[b], screen[c]
                M = np.array([[B[0] - A[0], Cc[0] - A[0]], [B[1] - A[1], Cc[1] - A[1]]])
                if abs(np.linalg.det(M)) < 1e-12:
                    continue
                u, w = np.linalg.solve(M, p - A[:2])
                lam = (1 - u - w, u, w)
                if min(lam) < 0:
                    continue
                z = 1.0 / (lam[0] / A[2] + lam[1] / B[2] + lam[2] / Cc[2])
                if z < depth[j, i]:
                    depth[j, i] = z
                    image[j, i] = rgb[f]
    return image, depth


def test_square_covers_exactly_its_pixels():
    v, f = _square(2.0, 3.0, 6.0, 7.0, 1.0)
    image, depth = V.rasterize(v, f, np.array([RED, RED], np.uint8), 10, 9)
    expected = np.zeros((9, 10), bool)
    expected[3:7, 2:6] = True  # pixel centres 2.5..5.5 and 3.5..6.5
    assert (_covered(image) == expected).all()
    assert (image[expected] == RED).all()
    assert np.allclose(depth[expected], 1.0) and np.isinf(depth[~expected]).all()


def test_right_triangle_pixel_count():
    # centres (i + .5, j + .5) with x + y <= 8 inside: i + j <= 7, 36 pixels; either winding
    v = np.array([[0, 0, 1.0], [8, 0, 1.0], [0, 8, 1.0]])
    for faces in (np.array([[0, 1, 2]]), np.array([[0, 2, 1]])):
        image, _ = V.rasterize(v, faces, np.array([BLUE], np.uint8), 12, 12)
        i, j = np.meshgrid(np.arange(12), np.arange(12))
        assert (_covered(image) == (i + j <= 7)).all()


def test_nearest_triangle_wins_whatever_the_order():
    near, fn = _square(1, 1, 7, 7, 1.0)
    far, ff = _square(4, 4, 10, 10, 2.0)
    both = np.concatenate([near, far])
    for faces, rgb in ((np.concatenate([fn, ff + 4]), [RED, RED, BLUE, BLUE]),
                       (np.concatenate([ff + 4, fn]), [BLUE, BLUE, RED, RED])):
        image, depth = V.rasterize(both, faces, np.array(rgb, np.uint8), 12, 12)
        assert (image[5, 5] == RED).all() and depth[5, 5] == pytest.approx(1.0)
        assert (image[8, 8] == BLUE).all() and depth[8, 8] == pytest.approx(2.0)
        assert (image[2, 2] == RED).all()


def test_equal_depth_goes_to_lower_face_index():
    v, f = _square(0, 0, 6, 6, 1.0)
    faces = np.concatenate([f, f])
    image, _ = V.rasterize(v, faces, np.array([RED, RED, BLUE, BLUE], np.uint8), 6, 6)
    assert (image == RED).all()


def test_perspective_correct_depth():
    # a plane seen by a pinhole: depth at each pixel is where the pixel's ray meets it
    cam = V.Camera(eye=np.zeros(3), rot=np.eye(3), focal=20.0, width=40, height=30)
    world = np.array([[-1.0, -1.0, 1.0], [1.0, -1.0, 3.0], [1.0, 1.0, 3.0], [-1.0, 1.0, 1.0]])
    _, depth = V.rasterize(cam.project(world), np.array([[0, 1, 2], [0, 2, 3]]),
                           np.array([RED, RED], np.uint8), 40, 30)
    j, i = np.nonzero(np.isfinite(depth))
    assert len(i) > 200
    # plane z = 2 + x; ray (u, v, 1) with u = (i + .5 - 20) / 20 meets it at z = 2 / (1 - u)
    u = (i + 0.5 - 20) / 20
    assert np.allclose(depth[j, i], 2.0 / (1.0 - u))


def test_matches_naive_reference(monkeypatch):
    rng = np.random.default_rng(3)
    W, H = 24, 18
    screen = np.concatenate([rng.uniform([-4, -4, 1], [W + 4, H + 4, 5], size=(30, 3)),
                             rng.uniform([0, 0, 1], [W, H, 5], size=(30, 3))])
    faces = np.concatenate([rng.integers(0, 30, size=(6, 3)),  # large triangles
                            30 + np.arange(30).reshape(10, 3)])
    rgb = rng.integers(0, 256, size=(len(faces), 3)).astype(np.uint8)
    # a tiny chunk budget: every size bucket is split into several chunks
    monkeypatch.setattr(V, "FRAGMENT_BUDGET", 64)
    image, depth = V.rasterize(screen, faces, rgb, W, H)
    ref_image, ref_depth = naive_rasterize(screen, faces, rgb, W, H)
    assert (np.isfinite(depth) == np.isfinite(ref_depth)).all()
    assert np.allclose(depth[np.isfinite(depth)], ref_depth[np.isfinite(ref_depth)])
    assert (image == ref_image).all()


def test_triangles_behind_the_camera_are_culled():
    v, f = _square(0, 0, 6, 6, -1.0)
    image, _ = V.rasterize(v, f, np.array([RED, RED], np.uint8), 6, 6)
    assert not _covered(image).any()


def test_fit_camera_keeps_the_box_in_view():
    lo, hi = np.array([-0.3, 0.7, 0.2]), np.array([0.4, 1.1, 0.6])
    for az, el in ((0, 0), (35, 25), (-70, 60)):
        cam = V.fit_camera(lo, hi, np.array([0, 1.0, 0]), np.array([0, 0, 1.0]), 320, 180,
                           az, el)
        corners = np.array([[a, b, c] for a in (lo[0], hi[0]) for b in (lo[1], hi[1])
                            for c in (lo[2], hi[2])])
        p = cam.project(corners)
        assert (p[:, 2] > 0).all()
        assert (p[:, 0] >= 0).all() and (p[:, 0] <= 320).all()
        assert (p[:, 1] >= 0).all() and (p[:, 1] <= 180).all()
        # the box fills the view along at least one axis (tight fit)
        span = np.ptp(p[:, :2], axis=0) / np.array([320, 180])
        assert span.max() > 0.8 * V.FIT_MARGIN
        assert np.allclose(cam.project((lo + hi) / 2)[:2], [160, 90])
    # up stays up on screen: a point above the centre is drawn higher (smaller y)
    cam = V.fit_camera(lo, hi, np.array([0, 1.0, 0]), np.array([0, 0, 1.0]), 320, 180)
    assert cam.project(np.array([0.05, 1.2, 0.4]))[1] < cam.project(np.array([0.05, 0.8, 0.4]))[1]


def test_contact_colours_and_lambert():
    base = (0.2, 0.4, 0.6)
    c = V.contact_colours(np.array([0.0, V.CONTACT_NEAR, 0.5, V.CONTACT_FAR]), base)
    assert np.allclose(c[0], V.CONTACT_RGB) and np.allclose(c[1], V.CONTACT_RGB)
    assert np.allclose(c[2], base) and np.allclose(c[3], base)
    tri = np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], float)  # normal +z
    lit = V.lambert(tri, np.array([1.0, 1.0, 1.0]), np.array([0, 0, 1.0]))
    grazing = V.lambert(tri, np.array([1.0, 1.0, 1.0]), np.array([1.0, 0, 0]))
    assert np.allclose(lit, V.AMBIENT + V.DIFFUSE) and np.allclose(grazing, V.AMBIENT)


def _frames(n, w=64, h=48):
    """Moving squares: n frames (h, w, 3) uint8, deterministic."""
    out = []
    for t in range(n):
        f = np.full((h, w, 3), 240, np.uint8)
        f[10:30, 2 + t % 30:22 + t % 30] = (200, 60, 40)
        out.append(f)
    return out


def test_mp4_and_gif_decode_with_the_right_frames(tmp_path):
    import imageio.v2 as imageio
    from PIL import Image

    w = V.write_video(iter(_frames(31)), tmp_path / "a.mp4", tmp_path / "a.gif", 30.0)
    assert w.n_frames == 31 and w.gif_frames == 11  # every 3rd frame for 10 fps
    reader = imageio.get_reader(tmp_path / "a.mp4")
    frames = [f for f in reader]
    assert len(frames) == 31 and frames[0].shape == (48, 64, 3)
    assert reader.get_meta_data()["fps"] == pytest.approx(30.0)
    # lossy, but close: the square is where it was drawn
    assert np.abs(frames[5].astype(int) - _frames(31)[5].astype(int)).mean() < 6
    gif = Image.open(tmp_path / "a.gif")
    assert gif.n_frames == 11 and gif.size == (32, 24)
    assert gif.info["duration"] == 100 and gif.info["loop"] == 0
    assert w.gif_bytes == (tmp_path / "a.gif").stat().st_size < 20_000


def test_outputs_are_byte_stable(tmp_path):
    for name in ("a", "b"):
        V.write_video(iter(_frames(12)), tmp_path / f"{name}.mp4", tmp_path / f"{name}.gif", 30.0)
    assert (tmp_path / "a.gif").read_bytes() == (tmp_path / "b.gif").read_bytes()
    assert (tmp_path / "a.mp4").read_bytes() == (tmp_path / "b.mp4").read_bytes()


def test_size_and_output_checks(tmp_path):
    assert V.check_size((640, 360)) == (640, 360)
    for bad in ((641, 360), (640, 361), (16, 16)):
        with pytest.raises(InputError, match="even"):
            V.check_size(bad)
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="not a writable folder"):
        V.check_writable(tmp_path / "file" / "out.mp4", ".mp4", "--video")
    with pytest.raises(InputError, match="expected a .mp4"):
        V.check_writable(tmp_path / "out.avi", ".mp4", "--video")
    assert V.check_writable(tmp_path / "new" / "deep" / "o.gif", ".gif", "--gif").name == "o.gif"


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    from tests.grab_fixtures import write_dataset

    root = tmp_path_factory.mktemp("render_data")
    write_dataset(root, [("s1", "mug", "lift")], T=6)
    return root


def test_render_pair_same_sequence_gives_identical_panels(tiny_data, tmp_path):
    import imageio.v2 as imageio

    from grip_bench.data.grab_io import read_grab

    seq = read_grab(tiny_data / "grab" / "s1" / "mug_lift_1.npz")
    opts = V.RenderOptions(size=(128, 64))
    w = V.render_pair(seq, seq, ("", ""), tmp_path / "v.mp4", tmp_path / "v.gif", range(1, 5),
                      opts)
    assert w.n_frames == 4 and w.gif_frames == 2
    frames = [f for f in imageio.get_reader(tmp_path / "v.mp4")]  # list() asks len(): inf
    assert len(frames) == 4 and frames[0].shape == (64, 128, 3)
    # the frames before encoding: hands and object drawn, both panels the same pixels
    posed = V.pose_sequence(seq, range(2), _mesh(seq))
    raw = list(V.pair_frames(posed, posed, ("", ""), V.up_axis(seq), V.facing(seq), opts))
    assert len(raw) == 2 and raw[0].shape == (64, 128, 3)
    # the divider covers columns 63 and 64; panel pixel x is column x (left), 64 + x (right)
    assert (raw[0][:, 1:63] == raw[0][:, 65:127]).all()
    assert _covered(raw[0][:, :63]).mean() > 0.02


def _mesh(seq):
    from grip_bench.data.posing import load_object_mesh_of

    return load_object_mesh_of(seq)


def test_render_pair_rejects_length_mismatch(tiny_data, tmp_path):
    from grip_bench.data.grab_io import read_grab

    seq = read_grab(tiny_data / "grab" / "s1" / "mug_lift_1.npz")
    with pytest.raises(InputError, match="frames, but the ground truth has 6"):
        V.render_pair(seq, seq.frames(0, 5), ("", ""), tmp_path / "v.mp4")
    assert not (tmp_path / "v.mp4").exists()


def test_hand_near_the_object_turns_red(tiny_data):
    from grip_bench.data.grab_io import read_grab

    seq = read_grab(tiny_data / "grab" / "s1" / "mug_lift_1.npz")
    posed = V.pose_sequence(seq, range(2), _mesh(seq))
    # distances are to the box's surface: a vertex at the box centre is half the smallest
    # extent away (box 0.08 x 0.05 x 0.12 m)
    from tests.grab_fixtures import BOX_EXTENTS

    centre = posed.obj[0].mean(axis=0)
    d = V._surface_distance(*_mesh(seq))
    R = seq.object_rotations()[0]
    local = (centre - seq.object["transl"][0]) @ R.T
    assert d(local[None])[0] == pytest.approx(min(BOX_EXTENTS) / 2, abs=1e-6)
    assert posed.hand_dist["right"].shape == posed.hands["right"].shape[:2]


def test_pose_sequence_honours_a_frame_step(tiny_data):
    from grip_bench.data.grab_io import read_grab

    seq = read_grab(tiny_data / "grab" / "s1" / "mug_lift_1.npz")
    every = V.pose_sequence(seq, range(6), _mesh(seq))
    some = V.pose_sequence(seq, range(0, 6, 2), _mesh(seq))
    assert len(some.obj) == 3
    assert np.allclose(some.obj, every.obj[::2])
    assert np.allclose(some.hands["left"], every.hands["left"][::2])
    assert np.allclose(some.hand_dist["right"], every.hand_dist["right"][::2])
