"""Tests of rfmitsuba.splat.render: parity with a dense float64 reference,
finite-difference gradients, a closed-form peak, bad input, no recompilation."""
from __future__ import annotations

import math

import drjit as dr

import numpy as np
import pytest

from rfmitsuba.core import backend as B
from rfmitsuba.core.errors import GaussianError
from rfmitsuba.splat import as_jit_array, render
from rfmitsuba.splat import reference as ref


def random_scene(rng, n, *, box=((-3, -3, -1.5), (3, 3, 2.5)), scale=(0.08, 0.5)):
    means = rng.uniform(*box, (n, 3))
    log_scales = np.log(rng.uniform(*scale, (n, 3)))
    rotations = rng.normal(size=(n, 4))
    opacities = rng.uniform(0.05, 0.98, n)
    signals = rng.uniform(-0.5, 2.0, n)
    return means, log_scales, rotations, opacities, signals


def to_jit(means, log_scales, rotations, opacities, signals):
    """numpy -> Dr.Jit arrays via the public converter (no size in any kernel,
    which the recompilation test below checks)."""
    kinds = ("Array3f", "Array3f", "Array4f", "Float", "Float")
    return tuple(as_jit_array(a, k) for a, k in zip((means, log_scales, rotations, opacities, signals), kinds))


def assert_close(img, expected, tol=2e-5):
    """Max error relative to max(1, |expected|), outside pixels where an alpha sits
    on the skip threshold (``expected`` may be a (image, ambiguous-mask) pair)."""
    expected, amb = expected if isinstance(expected, tuple) else (expected, np.zeros(expected.shape, bool))
    assert amb.mean() < 0.002, "too many threshold pixels for a meaningful comparison"
    scale = max(1.0, float(np.abs(expected).max()))
    err = float(np.abs(np.where(amb, 0.0, img - expected)).max())
    assert err <= tol * scale, f"max error {err:.3g} (scale {scale:.3g})"


def test_parity_random_scenes_several_views(variant):
    rng = np.random.default_rng(0)
    scene = random_scene(rng, 80)
    rx = np.array([[0.1, 0.2, 0.0], [0.5, -0.3, 0.4], [-1.0, 1.0, 1.0]])
    for h, w in ((90, 360), (18, 72), (15, 50)):  # 15x50: tiles that do not divide the image
        img = render(*scene, rx, height=h, width=w).numpy()
        assert img.shape == (3, h, w)
        assert_close(img, ref.render(*scene, rx, height=h, width=w, ambiguous=True))


def test_parity_wrap_seam_zenith_near_receiver_and_below(variant):
    rng = np.random.default_rng(1)
    n = 24
    rx = np.array([0.3, -0.2, 1.0])
    # On the 0/360 seam (azimuth +-2 deg), at the zenith, within 0.3 m, and below the array.
    az = np.deg2rad(np.r_[rng.uniform(-2, 2, 6), rng.uniform(0, 360, 18)])
    el = np.deg2rad(np.r_[rng.uniform(0, 60, 6), rng.uniform(88.5, 90, 6), rng.uniform(-80, 80, 12)])
    dist = np.r_[rng.uniform(1, 4, 12), rng.uniform(0.07, 0.3, 6), rng.uniform(1, 3, 6)]
    d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], 1) * dist[:, None]
    means, log_scales, rotations, opacities, signals = random_scene(rng, n, scale=(0.05, 0.3))
    means = rx + d
    scene = (means, log_scales, rotations, opacities, signals)
    img = render(*scene, rx[None], height=90, width=360).numpy()
    expected, amb = ref.render(*scene, rx[None], height=90, width=360, ambiguous=True)
    assert_close(img, (expected, amb))
    assert np.abs(expected[0, :, :3]).max() > 0.1 and np.abs(expected[0, :, -3:]).max() > 0.1  # seam drawn
    assert np.abs(expected[0, -1]).max() > 0.1  # zenith row drawn


def test_rotated_array_frame_and_per_view_arrays(variant):
    rng = np.random.default_rng(2)
    n, views = 40, 2
    scene = random_scene(rng, n)
    per_view_signals = rng.uniform(0, 1, views * n)  # B*N signals, shared geometry
    c, s = math.cos(0.7), math.sin(0.7)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ np.array([[1, 0, 0], [0, 0.8, -0.6], [0, 0.6, 0.8]])
    rx = np.array([[0.0, 0.0, 0.5], [1.0, 0.5, 0.0]])
    args = scene[:4] + (per_view_signals,)
    img = render(*args, rx, rx_to_world=rot, height=18, width=72).numpy()
    assert_close(img, ref.render(*args, rx, rx_to_world=rot, height=18, width=72, ambiguous=True))


def test_isotropic_gaussian_peaks_at_its_direction(variant):
    # Azimuth 123 deg, elevation 34 deg, 3 m away: the brightest pixel is column 123, row 33.
    az, el = np.deg2rad(123.0), np.deg2rad(34.0)
    rx = np.array([0.5, -1.0, 1.2])
    mean = rx + 3.0 * np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    img = render(mean[None], np.full((1, 3), math.log(0.1)), [[1.0, 0, 0, 0]], [0.9], [1.0],
                 rx[None]).numpy()[0]
    i, j = np.unravel_index(np.argmax(img), img.shape)
    assert (i, j) == (33, 123)
    assert img[i, j] == pytest.approx(0.9, abs=1e-4)  # alpha at the centre = opacity
    # The footprint is symmetric about the centre (isotropic, small-angle).
    assert img[i, j - 1] == pytest.approx(img[i, j + 1], rel=0.05)


def gradient_check(scene, rx, h, w, rng):
    weights = rng.normal(size=(len(rx), h, w))
    jit = to_jit(*scene)
    for a in jit:
        dr.enable_grad(a)
    img = render(*jit, rx, height=h, width=w)
    dr.backward(dr.sum(img.array * B.Float(np.float32(weights.ravel()))))
    grads = [np.asarray(dr.grad(a).numpy(), np.float64) for a in jit]
    grads = [g.T if g.ndim == 2 else g for g in grads]
    errors = {}
    eps = 1e-7  # small: a larger step may carry a pixel across the alpha skip threshold
    names = ("means", "log_scales", "rotations", "opacities", "signals")
    for k, (name, base) in enumerate(zip(names, scene)):
        fd = np.zeros(base.shape)
        for idx in np.ndindex(base.shape):
            vals = []
            for sign in (1, -1):
                p = [np.array(x, np.float64, copy=True) for x in scene]
                p[k][idx] += sign * eps
                vals.append((ref.render(*p, rx, height=h, width=w) * weights).sum())
            fd[idx] = (vals[0] - vals[1]) / (2 * eps)
        errors[name] = np.abs(fd - grads[k]).max() / np.abs(fd).max()
    return errors


@pytest.mark.parametrize("tile_lanes", ["8", "16"])
def test_gradients_match_finite_differences(variant, tile_lanes, monkeypatch):
    # Reference derivatives: central differences of the float64 reference; the
    # AD gradient comes from the float32 kernel. Two views share the Gaussians.
    # Both rasteriser layouts (8 lanes of 8 pixels per tile: AVX2; 16 of 4: AVX-512).
    monkeypatch.setenv("RFMITSUBA_SPLAT_LANES", tile_lanes)
    rng = np.random.default_rng(3)
    scene = random_scene(rng, 16, box=((-2, -2, -1), (2, 2, 1.5)), scale=(0.15, 0.6))
    rx = np.array([[0.1, 0.2, 0.0], [0.4, -0.3, 0.3]])
    errors = gradient_check(scene, rx, 18, 72, rng)
    for name, err in errors.items():
        assert err < 5e-5, f"{name}: relative gradient error {err:.3g}"


def test_gradients_at_seam_and_zenith(variant):
    rng = np.random.default_rng(4)
    rx = np.array([[0.0, 0.0, 0.0]])
    # Across the 0/360 seam (above and below the array plane) and within 1.2 deg of
    # the zenith. (Not exactly on a pixel's antipode: a Gaussian wider than half the
    # azimuth circle is cut there, see rfmitsuba.splat.raster.)
    d = np.array([[2.0, -0.02, 0.3], [1.5, 0.05, -0.4], [0.01, 0.02, 2.0], [-0.03, 0.004, 1.5]])
    scene = random_scene(rng, 4, scale=(0.1, 0.4))
    scene = (d,) + scene[1:]
    errors = gradient_check(scene, rx, 18, 72, rng)
    for name, err in errors.items():
        assert err < 5e-5, f"{name}: relative gradient error {err:.3g}"


def test_empty_set_gives_zero_images(variant):
    img = render(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 4)), np.zeros(0), np.zeros(0),
                 np.zeros((2, 3)), height=18, width=72)
    assert img.shape == (2, 18, 72) and not np.any(img.numpy())


def test_culled_and_all_below_threshold_give_zero(variant):
    # One Gaussian closer than `near`, one with opacity below 1/255.
    img = render([[0.01, 0, 0], [2, 0, 0]], np.full((2, 3), -2.0), [[1, 0, 0, 0]] * 2, [0.9, 0.001],
                 [1.0, 1.0], [[0, 0, 0]], height=18, width=72).numpy()
    assert not np.any(img)


@pytest.mark.parametrize("field, value, message", [
    ("means", np.nan, "means: non-finite"),
    ("log_scales", np.inf, "log_scales"),
    ("log_scales", 200.0, "log_scales"),
    ("rotations", 0.0, "zero quaternion"),
    ("opacities", 1.5, "opacities"),
    ("signals", np.nan, "signals: non-finite"),
])
def test_bad_values_raise(variant, field, value, message):
    rng = np.random.default_rng(5)
    scene = dict(zip(("means", "log_scales", "rotations", "opacities", "signals"), random_scene(rng, 5)))
    scene[field] = np.array(scene[field], copy=True)
    scene[field][2] = value
    with pytest.raises(GaussianError, match=message):
        render(*scene.values(), [[0, 0, 0]], height=18, width=72)


def test_unchecked_bad_geometry_is_dropped_not_nan(variant):
    # check=False (the trainer's fast path): a NaN mean or zero quaternion drops
    # that Gaussian; the rest of the image is the reference without it.
    rng = np.random.default_rng(6)
    scene = [np.array(a, copy=True) for a in random_scene(rng, 10)]
    scene[0][3] = np.nan
    scene[2][7] = 0.0
    img = render(*scene, [[0, 0, 0]], height=18, width=72, check=False).numpy()
    keep = np.setdiff1d(np.arange(10), [3, 7])
    assert np.all(np.isfinite(img))
    assert_close(img, ref.render(*[a[keep] for a in scene], [[0, 0, 0]], height=18, width=72, ambiguous=True))


def test_size_and_shape_errors(variant):
    rng = np.random.default_rng(7)
    m, ls, rot, op, sig = random_scene(rng, 6)
    with pytest.raises(GaussianError, match="size N or B\\*N"):
        render(m, ls, rot, op[:5], sig, [[0, 0, 0]])
    with pytest.raises(GaussianError, match="size N or B\\*N"):
        render(m, ls, rot, op, np.ones(18), [[0, 0, 0], [1, 1, 1]])  # 3N with B = 2
    with pytest.raises(GaussianError, match="rx_positions"):
        render(m, ls, rot, op, sig, [[0, 0]])
    with pytest.raises(GaussianError, match="rx_positions: non-finite"):
        render(m, ls, rot, op, sig, [[0, 0, np.nan]])
    with pytest.raises(GaussianError, match="rx_to_world"):
        render(m, ls, rot, op, sig, [[0, 0, 0]], rx_to_world=np.ones((3, 3)))
    with pytest.raises(GaussianError, match="shape \\[N, 4\\]"):
        render(m, ls, rot[:, :3], op, sig, [[0, 0, 0]])
    with pytest.raises(GaussianError, match="height and width"):
        render(m, ls, rot, op, sig, [[0, 0, 0]], height=0)


def test_no_recompilation_when_n_or_batch_changes(variant):
    """A training step (render, SSIM loss, backward) at several N and batch sizes launches the
    same kernels: densification and a short last batch must not recompile.

    The renderer's forward kernels are compared by hash (not cache hits, so the on-disk cache of
    earlier runs cannot hide a recompile): a literal that leaked into a kernel changes its hash.
    The loss and the backward pass are compared by each kernel's operation count: on the
    renderer's AD-tracked image, Dr.Jit fuses their pending work in an order that varies from
    run to run (measured here: most runs launched some loss or backward kernels of new hashes but
    the same structure, with the same inputs; the forward render alone repeated its hashes in 6
    of 6 runs), so their hashes are not reproducible even without any recompile."""
    from rfmitsuba.train import loss as ssim

    rng = np.random.default_rng(8)

    def step(n, views):
        jit = to_jit(*random_scene(rng, n))
        for a in jit:
            dr.enable_grad(a)
        rx = rng.uniform(-1, 1, (views, 3))
        target = B.TensorXf(np.float32(rng.uniform(0, 1, (views, 18, 72))))
        dr.kernel_history_clear()
        img = render(*jit, rx, height=18, width=72, check=False)
        dr.eval(img)
        fwd = {h["hash"]: (h["operation_count"], h["size"]) for h in dr.kernel_history([dr.KernelType.JIT])}
        value = ssim.loss(img, target)
        dr.backward(value)
        dr.eval([dr.grad(a) for a in jit])
        bwd = {h["operation_count"] for h in dr.kernel_history([dr.KernelType.JIT])}
        return fwd, bwd

    with dr.scoped_set_flag(dr.JitFlag.KernelHistory):
        (f1, b1), (f2, b2) = step(50, 2), step(60, 3)  # warm-up, both batch sizes
        seen, seen_ops = {**f1, **f2}, b1 | b2
        later = {(n, v): step(n, v) for n, v in ((90, 2), (131, 3), (64, 2), (200, 3), (1000, 2))}
    assert len(seen) >= 2 and len(seen_ops) >= 3  # projection, forward loop, backward loop at least
    for key, (fwd, bwd) in later.items():
        new = [fwd[h] for h in set(fwd) - set(seen)]
        assert not new, f"(N, B) = {key}: render kernels (ops, size) not seen before: {new}"
        assert bwd <= seen_ops, f"(N, B) = {key}: loss or backward kernels of new structure (ops): {sorted(bwd - seen_ops)}"


def test_reference_twin_constants_equal_the_kernels():
    """The NumPy twin writes the kernel constants again (independently): they must agree."""
    from rfmitsuba.splat import project, tiles

    assert ref.ALPHA_MIN == tiles.ALPHA_MIN and ref.ALPHA_MAX == tiles.ALPHA_MAX
    assert ref.DILATION == project.DILATION and ref.ZENITH_EPS == project.ZENITH_EPS
