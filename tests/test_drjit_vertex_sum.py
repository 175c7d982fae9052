"""Smooth-shading normals in the Dr.Jit backend: the per-vertex sums of face normals
(``raster._vertex_sums``) give the same bits in any summation order (a float scatter-add's order
varies across threads, which moved shaded colours by an ulp from run to run), close to the exact
sums, with derivatives through the ordinary scatter-add."""
from __future__ import annotations

import math

import numpy as np
import pytest

dr = pytest.importorskip("drjit", reason="the Dr.Jit backend needs drjit (pip install gendr[drjit])")

import gendr_drjit.raster as R  # noqa: E402


def _types(double):
    import drjit.llvm.ad as m
    return R.Types(m, double)


def _case(seed, n_faces=3000, n_slots=400):
    rng = np.random.default_rng(seed)
    values = rng.standard_normal(n_faces) * np.exp(rng.uniform(-8, 0, n_faces))  # magnitudes over 8 e-folds
    slots = [rng.integers(0, n_slots, n_faces) for _ in range(3)]
    return values, slots, n_slots


@pytest.mark.parametrize("double", [False, True], ids=["float32", "float64"])
def test_vertex_sums_do_not_depend_on_the_order(double):
    """The same terms scattered in another lane order: bit-identical sums (a float scatter-add of
    these terms in the two orders differs, checked below, so the test can fail), each within one
    rounding of the exact sum (math.fsum)."""
    T = _types(double)
    values, slots, n = _case(0)
    perm = np.random.default_rng(1).permutation(len(values))
    out = []
    for order in (np.arange(len(values)), perm):
        v = T.Float(values[order])
        out.append(R._vertex_sums(T, [v], [T.UInt32(s[order].astype(np.uint32)) for s in slots], n)[0].numpy())
    np.testing.assert_array_equal(out[0], out[1])
    # the exact sums of the terms as the device holds them (float32 rounds them first); each sum is
    # rounded once, and each term to the integer grid 2^−k: count·2^−(k+1) absolute at most
    held = values.astype(np.float32).astype(np.float64) if not double else values
    exact = np.array([math.fsum(np.concatenate([held[sl == k] for sl in slots])) for k in range(n)])
    count = np.bincount(np.concatenate(slots), minlength=n).max()
    k = 61 - math.ceil(math.log2(np.abs(held).max() * count))
    eps = np.finfo(np.float64 if double else np.float32).eps
    np.testing.assert_allclose(out[0], exact, rtol=eps / 2, atol=count * 2.0 ** -(k + 1))

    plain = []  # the float scatter-add the sums replace: order-dependent on this data
    for order in (np.arange(len(values)), perm):
        acc = dr.zeros(T.Float, n)
        for s in slots:
            dr.scatter_reduce(dr.ReduceOp.Add, acc, T.Float(values[order]), T.UInt32(s[order].astype(np.uint32)))
        plain.append(acc.numpy())
    assert not np.array_equal(plain[0], plain[1])


def test_vertex_sum_gradient_is_the_scatter_adds():
    T = _types(True)
    values, slots, n = _case(2, n_faces=50, n_slots=7)
    v = T.Float(values)
    dr.enable_grad(v)
    w = T.Float(np.arange(1.0, n + 1.0))
    dr.backward(dr.sum(R._vertex_sums(T, [v], [T.UInt32(s.astype(np.uint32)) for s in slots], n)[0] * w))
    want = sum((np.arange(1.0, n + 1.0))[s] for s in slots)
    np.testing.assert_array_equal(dr.grad(v).numpy(), want)
