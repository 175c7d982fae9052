"""The reference implementation's distance cut-off (``Renderer(cutoff=...)``, its ``dist_eps``).

A face contributes nothing to an outside pixel whose squared distance to it is >= cutoff·τ; every
other pixel is unchanged. Checked on one triangle against the closed form, for both backends,
plain and squared; against the torch backend on the parity scene (images and gradients, float64);
and a cut-off beyond every distance changes nothing.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

import gendr  # noqa: E402
from gendr.errors import ParameterError  # noqa: E402

BACKENDS = ["torch"] + (["drjit"] if "drjit" in gendr.available_backends() else [])
# one triangle in the plane z = 0 seen head-on by an orthographic camera: screen = world x, y
TRI = np.array([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0]])
H = W = 40


def _alpha(backend, dist, tau, cutoff, eps=0.0):
    r = gendr.Renderer(dist, "probabilistic", tau=tau, image_size=(H, W), eps=eps, blend=None, backend=backend,
                       cutoff=cutoff)
    cam = gendr.OrthographicCamera(eye=(0.0, 0.0, 2.0), xmag=1.0, ymag=1.0)
    img = r.render(torch.tensor(TRI), torch.tensor([[0, 1, 2]]), cam)
    return np.asarray(r.to_numpy(img))[0, ..., 3]


def _signed_distance_grid():
    """Signed distance (inside > 0) of every pixel centre to TRI, float64, by brute force."""
    j, i = np.meshgrid(np.arange(W), np.arange(H))
    p = np.stack([2 * (j + 0.5) / W - 1, 1 - 2 * (i + 0.5) / H], -1)
    a, b, c = TRI[:, :2]
    dist = np.full((H, W), np.inf)
    inside = np.ones((H, W), bool)
    for s, e in ((a, b), (b, c), (c, a)):
        ed = e - s
        t = np.clip(((p - s) @ ed) / (ed @ ed), 0, 1)
        q = p - (s + t[..., None] * ed)
        dist = np.minimum(dist, np.hypot(q[..., 0], q[..., 1]))
        inside &= (ed[0] * (p[..., 1] - s[1]) - ed[1] * (p[..., 0] - s[0])) > 0  # counter-clockwise
    return np.where(inside, dist, -dist)


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("squared", [False, True])
def test_one_triangle_matches_the_closed_form(backend, squared):
    """alpha = F(x) where the pixel is inside or d² < cutoff·τ, else 0 (one face: A = p)."""
    tau, cutoff = (0.002, 50.0) if squared else (0.05, 4.0)  # cut at 0.316 / 0.447 screen units
    d = _signed_distance_grid()
    x = d * np.abs(d) / tau if squared else d / tau
    F = 0.5 + np.arctan(x) / math.pi  # cauchy: heavy-tailed, so the cut-off is what drops pixels
    want = np.where((d >= 0) | (d * d < cutoff * tau), F, 0.0)
    got = _alpha(backend, gendr.distribution("cauchy", squared=squared), tau, cutoff)
    assert (want == 0).sum() > 100 and ((want > 0) & (d < 0)).sum() > 100  # both sides are exercised
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    # without the cut-off every pixel keeps its coverage
    np.testing.assert_allclose(_alpha(backend, gendr.distribution("cauchy", squared=squared), tau, None), F,
                               rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("backend", BACKENDS)
def test_a_cutoff_beyond_every_distance_changes_nothing(backend):
    dist = gendr.distribution("logistic")
    np.testing.assert_array_equal(_alpha(backend, dist, 0.05, 1e6, eps=1e-4), _alpha(backend, dist, 0.05, None, eps=1e-4))


@pytest.mark.skipif("drjit" not in BACKENDS, reason="needs the Dr.Jit backend")
@pytest.mark.parametrize("dist,blend", [(("cauchy", {}), None), (("reciprocal", {"squared": True}), None),
                                        (("levy", {"reversed": True}), "softmax"), (("logistic", {}), "hard")])
def test_backends_agree_with_a_cutoff(dist, blend):
    from test_drjit_parity import F64_TOL, run
    d, t = gendr.distribution(dist[0], **dist[1]), gendr.tconorm("einstein")
    ref = run("torch", d, t, blend=blend, cutoff=0.5 if not d.squared else 2.0)
    got = run("drjit", d, t, blend=blend, cutoff=0.5 if not d.squared else 2.0)
    full = run("torch", d, t, blend=blend)
    assert float((ref[0] - full[0]).abs().max()) > 1e-3  # the cut-off is active on this scene
    assert float((ref[0] - got[0]).abs().max()) <= F64_TOL
    for k, g in ref[1].items():
        assert float((g - got[1][k]).abs().max()) <= F64_TOL * max(1.0, float(g.abs().max())), k


@pytest.mark.parametrize("bad", [0.0, -1.0, math.inf, "100", True])
def test_bad_cutoff_is_a_parameter_error(bad):
    with pytest.raises(ParameterError, match="cutoff"):
        gendr.Renderer("cauchy", cutoff=bad)
