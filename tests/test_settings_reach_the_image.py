"""Every Renderer constructor argument reaches the image, on every backend.

tests/test_renderer_reference.py feeds the naive reference (naive_reference.py) the settings read
back from the renderer under test (``r.settings``): a Renderer that drops or mis-stores an
argument (renders with the default γ whatever ``gamma`` says, swaps ``ambient`` and ``diffuse``,
ignores ``light_direction``) hands the reference the same wrong values, and the two agree. Here the
reference gets the values *as passed to the constructor*, written once in this file, never read
back from the renderer.

Each test also checks that it can fail: the reference image with any one argument at its default
(or with ambient and diffuse swapped) must differ from the expected image by far more than the
tolerance, so that no argument is "covered" by a scene where it has no visible effect.

Tolerance: TOL = 1e-9 absolute, as in test_renderer_reference.py: both sides evaluate the same
float64 formulas in another order (rounding ~1e-14), while a dropped argument moves pixels by
> SENSITIVITY = 1e-3 (asserted).
"""
from __future__ import annotations

import numpy as np
import pytest
import torch

import gendr
from naive_reference import pixel_face_geometry, render_naive

TOL = 1e-9  # float64, absolute (see the module docstring)
SENSITIVITY = 1e-3  # the least a dropped argument must change the image by, for the check to mean anything
BACKENDS = ["torch", "drjit"]


def _backend_ok(name):
    try:
        gendr.Renderer(image_size=2, backend=name)
    except gendr.BackendUnavailableError:
        pytest.skip(f"backend {name} unavailable")


#: a tiny scene: two overlapping faces at different depths (the softmax's γ and the background's ε
#: decide how they mix), a tilted one (the light direction decides its shade), and a back-facing one
#: (wound clockwise as seen from the camera: cull_backfaces drops it from the RGB)
_V = np.array([
    [-0.9, -0.7, 0.0], [0.6, -0.6, 0.0], [-0.2, 0.8, 0.0],          # 0: at z = 0
    [-0.3, -0.4, 0.4], [0.8, 0.0, 0.25], [0.0, 0.7, 0.5],           # 1: nearer, overlaps 0
    [0.3, 0.2, -0.4], [1.1, 0.5, 0.3], [0.5, 0.95, -0.2],          # 2: tilted
    [-1.2, 0.1, 0.1], [-0.7, 0.9, 0.2], [-0.6, 0.2, 0.6],          # 3: clockwise on screen
])
_F = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8], [9, 10, 11]])
_COLORS = np.random.default_rng(5).uniform(0.2, 1.0, (len(_V), 3))
_CAMERA = dict(eye=(0.15, 0.1, 3.0), fov_y=45.0)

#: the constructor's documented defaults (Renderer.__init__, docs/conventions.md)
DEFAULTS = dict(distribution=("logistic", {}), tconorm=("probabilistic", {}), tau=0.01, eps=1e-4, gamma=1e-4,
                background_eps=1e-3, background=(0.0, 0.0, 0.0), ambient=0.5, diffuse=0.5,
                light_direction=(0.0, 0.0, -1.0), cull_backfaces=False)
#: a non-default value for each of them (the light is not a unit vector: the renderer normalises it)
VALUES = dict(distribution=("gaussian", {}), tconorm=("einstein", {}), tau=0.08, eps=0.02, gamma=0.05,
              background_eps=0.9, background=(0.2, 0.5, 0.9), ambient=0.15, diffuse=0.7,
              light_direction=(0.8, -0.6, -1.3), cull_backfaces=True)
SIZE = (12, 16)  # (H, W), not the default 256 and not square
#: the arguments each blend's RGB or alpha depends on (γ and ε_bg are the softmax's only)
MATTERS = {"softmax": list(VALUES), "hard": [k for k in VALUES if k not in ("gamma", "background_eps")]}


def _make(spec, factory):
    name, params = spec
    return factory(name, **params)


def _fast(backend, blend, values):
    v = dict(values)
    r = gendr.Renderer(_make(v.pop("distribution"), gendr.distribution), _make(v.pop("tconorm"), gendr.tconorm),
                       tau=v.pop("tau"), image_size=SIZE, backend=backend, eps=v.pop("eps"), blend=blend,
                       max_pairs=40,  # many row bands: the band size must not change the image either
                       **v)
    img = r.render(_V, _F, gendr.PerspectiveCamera(**_CAMERA), vertex_colors=_COLORS)
    return np.asarray(r.to_numpy(img), dtype=np.float64)[0]


def _naive(blend, values):
    v = dict(values)
    img = render_naive(torch.tensor(_V), torch.tensor(_F), gendr.PerspectiveCamera(**_CAMERA),
                       distribution=_make(v.pop("distribution"), gendr.distribution),
                       tconorm=_make(v.pop("tconorm"), gendr.tconorm), image_size=SIZE, blend=blend,
                       vertex_colors=torch.tensor(_COLORS), **v)
    return img.numpy()[0]


@pytest.mark.parametrize("blend", ["softmax", "hard"])
@pytest.mark.parametrize("backend", BACKENDS)
def test_every_constructor_argument_reaches_the_image(backend, blend):
    """A render with a non-default value of every image-affecting constructor argument (distribution,
    tconorm, tau, image_size, eps, blend, gamma, background_eps, background, ambient, diffuse,
    light_direction, cull_backfaces; max_pairs small, which must change nothing) equals the naive
    reference given those values explicitly. Catches a Renderer (or backend) that drops one of them,
    stores a default or another argument's value in its place, or does not normalise the light."""
    _backend_ok(backend)
    want = _naive(blend, VALUES)
    got = _fast(backend, blend, VALUES)
    assert got.shape == want.shape == (*SIZE, 4)
    err = np.abs(got - want).max()
    assert err <= TOL, f"{backend}, {blend}: max abs error {err:.3g} against the reference"
    # the check can fail: any one argument at its default changes the expected image
    for name in MATTERS[blend]:
        other = _naive(blend, dict(VALUES, **{name: DEFAULTS[name]}))
        assert np.abs(other - want).max() > SENSITIVITY, f"{name} has no visible effect in this scene"
    swapped = _naive(blend, dict(VALUES, ambient=VALUES["diffuse"], diffuse=VALUES["ambient"]))
    assert np.abs(swapped - want).max() > SENSITIVITY


@pytest.mark.parametrize("backend", BACKENDS)
def test_softmax_background_eps_alone(backend):
    """Only background_eps (and γ, so that it shows) differs from the defaults: the background's
    softmax weight exp(ε/γ) against the faces' p·exp(z̃/γ), z̃ ≈ 0.97 here. With ε = 0.9 and γ = 0.05
    the background weighs in wherever a face's coverage is below ~0.25; a renderer that ignores ε
    (keeps 1e-3) shows the faces' colour almost undiluted there."""
    _backend_ok(backend)
    values = dict(DEFAULTS, tau=0.08, gamma=0.05, background_eps=0.9, background=(0.3, 0.6, 0.1))
    want = _naive("softmax", values)
    got = _fast(backend, "softmax", values)
    assert np.abs(got - want).max() <= TOL
    assert np.abs(_naive("softmax", dict(values, background_eps=1e-3)) - want).max() > 0.05


@pytest.mark.parametrize("backend", BACKENDS)
def test_cutoff_reaches_the_image(backend):
    """``cutoff`` (the reference implementation's distance cut-off): a face adds no coverage to a
    pixel outside it whose squared distance to it is >= cutoff·τ. One face, a heavy-tailed
    distribution (cauchy, eps = 0: without the cut-off it reaches every pixel), so the expected
    alpha is the reference's where d² < cutoff·τ or d >= 0 (d: the reference's own signed distance)
    and exactly 0 beyond. Catches a dropped or mis-stored cutoff (None: the far pixels get ~0.02)."""
    _backend_ok(backend)
    tau, cutoff = 0.05, 2.0
    v, f = _V[:3], _F[:1]
    cam = gendr.PerspectiveCamera(**_CAMERA)
    r = gendr.Renderer("cauchy", "probabilistic", tau=tau, image_size=SIZE, backend=backend, eps=0.0, blend=None,
                       cutoff=cutoff)
    got = np.asarray(r.to_numpy(r.render(v, f, cam)), dtype=np.float64)[0, ..., 3]
    full = render_naive(torch.tensor(v), torch.tensor(f), cam, distribution=gendr.distribution("cauchy"),
                        tconorm=gendr.tconorm("probabilistic"), tau=tau, image_size=SIZE, eps=0.0).numpy()[0, ..., 3]
    d = pixel_face_geometry(torch.tensor(v), torch.tensor(f), cam, SIZE)[0].numpy()[0, 0]
    far = (d < 0) & (d * d >= cutoff * tau)
    # no pixel centre within 1e-9 of the cut-off circle, where the two sides could round differently
    assert np.abs(d * d - cutoff * tau).min() > 1e-9
    assert far.sum() > 20 and (~far).sum() > 20 and full[far].min() > 0.01
    np.testing.assert_allclose(got, np.where(far, 0.0, full), rtol=0, atol=TOL)
