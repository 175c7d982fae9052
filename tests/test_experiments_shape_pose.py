"""gendr_experiments: shape optimisation (§5.1), pose optimisation (§5.2) and their building blocks."""

import numpy as np
import pytest
import torch

from gendr_experiments.common import (axis_angle_to_matrix, config_hash, flatten_edges, flatten_loss,
                                      laplacian_loss, log_tau_schedule, mesh_laplacian, random_rotation,
                                      rotation_about, rotation_angle_deg, soft_iou_loss)
from gendr_experiments.pose import run_pose
from gendr_experiments.shape import ShapeProblem, SphereDeformer, run_shape
from gendr.scenes import icosphere


@pytest.fixture(autouse=True)
def _one_thread():
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)


def test_soft_iou_loss_values():
    a = torch.zeros(1, 4, 4)
    a[0, :2] = 1
    assert float(soft_iou_loss(a, a)) == pytest.approx(0.0, abs=1e-6)
    b = torch.zeros(1, 4, 4)
    b[0, 2:] = 1
    assert float(soft_iou_loss(a, b)) == pytest.approx(1.0, abs=1e-6)
    c = torch.zeros(1, 4, 4)
    c[0, 1:3] = 1  # IoU 4/12
    assert float(soft_iou_loss(a, c)) == pytest.approx(1 - 4 / 12, abs=1e-6)


def test_regularizers_vanish_where_expected():
    s = icosphere(2)
    v = torch.tensor(s.vertices, dtype=torch.float32)
    L = mesh_laplacian(len(v), s.faces)
    # a uniform Laplacian of a translated mesh does not change; of a plane grid's interior it is 0
    assert float(laplacian_loss(v + 3.0, L)) == pytest.approx(float(laplacian_loss(v, L)), rel=1e-4)
    assert torch.allclose(L.sum(1), torch.zeros(len(v)), atol=1e-6)
    fe = flatten_edges(s.faces)
    assert len(fe[0]) == 3 * s.num_faces // 2  # closed mesh: every edge interior
    # flat: two triangles in a plane -> 0; folded onto each other -> 4
    flat = torch.tensor([[0., 0, 0], [1, 0, 0], [0, 1, 0], [1, -1, 0]])
    faces = np.array([[0, 1, 2], [1, 0, 3]])
    assert float(flatten_loss(flat, flatten_edges(faces))) == pytest.approx(0.0, abs=1e-6)
    fold = flat.clone()
    fold[3] = torch.tensor([0.2, 1.0, 0.0])
    assert float(flatten_loss(fold, flatten_edges(faces))) == pytest.approx(4.0, abs=1e-3)
    # the sphere is smooth: a rough sphere has a larger loss
    noisy = v + 0.05 * torch.randn(v.shape, generator=torch.Generator().manual_seed(0))
    assert float(flatten_loss(noisy, fe)) > float(flatten_loss(v, fe))
    assert float(laplacian_loss(noisy, L)) > float(laplacian_loss(v, L))


def test_rotations():
    rng = np.random.default_rng(0)
    R = random_rotation(rng)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12) and np.linalg.det(R) == pytest.approx(1.0)
    for angle in (0.0, 3.0, 45.0, 179.0):
        Rd = rotation_about(rng.normal(size=3), angle)
        assert rotation_angle_deg(Rd @ R, R) == pytest.approx(angle, abs=1e-5)
    w = torch.tensor([0.1, -0.2, 0.3], dtype=torch.float64, requires_grad=True)
    M = axis_angle_to_matrix(w)
    assert torch.allclose(M @ M.T, torch.eye(3, dtype=torch.float64), atol=1e-12)
    assert torch.autograd.gradcheck(lambda x: axis_angle_to_matrix(x), (w,))
    z = torch.zeros(3, dtype=torch.float64, requires_grad=True)
    axis_angle_to_matrix(z).sum().backward()
    assert torch.isfinite(z.grad).all()


@pytest.mark.parametrize("w", [(0.1, -0.2, 0.3), (1.0, 2.0, -0.5), (3.0, 0.1, 0.0), (1e-4, 2e-4, -1e-4),
                               (0.03, 0.02, -0.025), (0.03, 0.02, -0.035), (0.0, 0.0, 0.0)])
def test_axis_angle_to_matrix_against_independent_references(w):
    # θ from 0 through the series/closed-form switch at 0.05 (0.046 and 0.051 above) to 3.0
    import kornia.geometry.conversions as kc
    w64 = torch.tensor(w, dtype=torch.float64)
    x, y, z = w
    exact = torch.linalg.matrix_exp(torch.tensor([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]], dtype=torch.float64))
    # matrix_exp (scaling and squaring) is itself off by ~1e-15 at θ ≈ 3 (kornia's Rodrigues: 1.1e-15)
    assert torch.allclose(axis_angle_to_matrix(w64), exact, rtol=0, atol=2e-15)
    # float32: the float64 matrix rounded once, so within half an ulp of 1 (kornia's own errs by up to 8e-8)
    R32 = axis_angle_to_matrix(w64.float())
    assert R32.dtype == torch.float32
    assert (R32.double() - exact).abs().max() <= 2.0 ** -25
    # gradient: finite differences, and kornia's Rodrigues differentiated by autograd (another code)
    wg = w64.clone().requires_grad_()
    assert torch.autograd.gradcheck(axis_angle_to_matrix, (wg,))
    G = torch.tensor([[0.3, -1.2, 0.7], [2.0, 0.1, -0.4], [-0.9, 0.5, 1.1]], dtype=torch.float64)
    (axis_angle_to_matrix(wg) * G).sum().backward()
    wk = w64.clone().requires_grad_()
    (kc.axis_angle_to_rotation_matrix(wk.reshape(1, 3))[0] * G).sum().backward()
    assert torch.allclose(wg.grad, wk.grad, rtol=0, atol=1e-12)


def test_tau_schedule_and_hash():
    assert log_tau_schedule(0, 5, 1e-1, 1e-5) == pytest.approx(1e-1)
    assert log_tau_schedule(2, 5, 1e-1, 1e-5) == pytest.approx(1e-3)
    assert log_tau_schedule(4, 5, 1e-1, 1e-5) == pytest.approx(1e-5)
    assert config_hash({"a": 1, "b": [1, 2]}) == config_hash({"b": [1, 2], "a": 1})
    assert config_hash({"a": 1}) != config_hash({"a": 2})


def test_sphere_deformer_starts_at_template():
    m = SphereDeformer(1)
    v = m().detach().numpy()
    assert np.allclose(v, icosphere(1, radius=0.5).vertices, atol=1e-5)


def test_shape_optimisation_lowers_the_loss():
    res = run_shape(dict(target="airplane", steps=25, image_size=32, views=6, lr=0.05, tau=0.02))
    assert res["steps_done"] == 25 and not res["nonfinite"]
    assert res["soft_loss_last"] < 0.8 * res["soft_loss_first"]
    assert res["metric"] < res["hard_iou_loss_initial"] - 0.1


def test_a_nonfinite_gradient_ends_the_shape_run_and_leaves_the_mesh(monkeypatch):
    # (the paper grid's reversed squared exponential with Dombi(4) and SS(-4) diverge so: a finite
    # loss, an infinite gradient, which Adam turned into a NaN mesh and the next render refused)
    import math
    cfg = dict(target="airplane", steps=4, image_size=16, views=2, lr=0.05, tau=0.02, metric="best")
    prob = ShapeProblem(cfg)
    assert math.isfinite(prob.step(0))
    before = [p.detach().clone() for p in prob.model.parameters()]
    prob.model.displace.register_hook(lambda g: g * math.inf)
    assert math.isnan(prob.step(1))
    assert all(torch.equal(p.detach(), q) for p, q in zip(prob.model.parameters(), before))

    init = ShapeProblem.__init__

    def poisoned(self, *a, **k):
        init(self, *a, **k)
        self.model.displace.register_hook(lambda g: g * math.inf)
    monkeypatch.setattr(ShapeProblem, "__init__", poisoned)
    res = run_shape(cfg)
    assert res["nonfinite"] and res["steps_done"] == 0 and math.isnan(res["hard_iou_loss_final"])
    assert res["metric"] == res["hard_iou_loss_initial"] and res["best_step"] == 0


def test_shape_optimisation_grid_instance_and_mesh_file(tmp_path):
    # a mesh file target (OBJ written here) and a grid instance (squared gaussian + einstein)
    import gendr
    chair = gendr.scenes.chair()
    path = tmp_path / "chair.obj"
    with open(path, "w") as f:
        for x in chair.vertices:
            f.write(f"v {x[0]} {x[1]} {x[2]}\n")
        for t in chair.faces:
            f.write(f"f {t[0] + 1} {t[1] + 1} {t[2] + 1}\n")
    inst = next(i for i in gendr.paper_grid() if i.name == "gaussian+sq|einstein")
    res = run_shape(dict(target=str(path), instance=inst.index, steps=15, image_size=24, views=4, lr=0.05))
    assert res["instance_label"] == "gaussian+sq|einstein"
    assert res["renderer_tau"] == pytest.approx(0.01 ** 2)
    assert res["metric"] < res["hard_iou_loss_initial"]


def test_pose_optimisation_recovers_a_small_perturbation():
    # tau decays 2e-2 -> 5e-3 here (a narrow range is enough for a 10 degree start)
    res = run_pose(dict(steps=120, image_size=64, lr=0.015, seed=1, angle_min=10, angle_max=10,
                        tau_start=0.02, tau_end=0.005))
    assert res["initial_error"] == pytest.approx(10.0, abs=1e-6)
    assert not res["nonfinite"]
    assert res["metric"] < 3.0 and res["success"]


def test_set_threads_gives_the_threads_to_the_rendering_backend():
    """drjit renders: torch keeps one thread (its idle OpenMP workers would spin beside Dr.Jit's
    kernels) and Dr.Jit gets the threads; torch renders: torch gets them; nonsense is refused."""
    from gendr.errors import ParameterError
    from gendr_experiments.common import set_threads
    dr = pytest.importorskip("drjit")
    n_dr = dr.thread_count()
    try:
        torch.set_num_threads(2)
        set_threads("drjit", 3)
        assert torch.get_num_threads() == 1 and dr.thread_count() == 3
        set_threads("torch", 2)
        assert torch.get_num_threads() == 2 and dr.thread_count() == 3
        set_threads("torch", None)
        assert torch.get_num_threads() == 2
        with pytest.raises(ParameterError, match="0"):
            set_threads("torch", 0)
    finally:
        dr.set_thread_count(n_dr)


def test_frozen_default_changes_no_number():
    """Dr.Jit renders of the experiments are frozen by default (make_renderer, and the shape step's
    hard renderer): the shape run's losses and metrics equal those of unfrozen renders bit for bit
    (one thread: deterministic sums), and the replays really happened (each recorded once)."""
    dr = pytest.importorskip("drjit")
    from gendr_experiments.shape import ShapeProblem
    cfg = dict(protocol="quick", backend="drjit", steps=4, views=2, image_size=24, subdivisions=1,
               distribution="logistic", tau=0.02)
    runs = []
    n_dr = dr.thread_count()
    dr.set_thread_count(1)
    try:
        for options in (None, {"freeze": False}):
            prob = ShapeProblem(cfg, backend_options=options)
            losses = [prob.step(i) for i in range(4)]
            runs.append((losses, prob.hard_iou_loss()[1], prob.model.displace.detach().clone()))
            if options is None:  # the soft render (forward, backward) and the hard one, each recorded once
                assert prob.renderer.backend.frozen.n_recordings == 2
                assert prob._hard.backend.frozen.n_recordings == 1
            else:
                assert prob.renderer.backend.frozen is None and prob._hard.backend.frozen is None
    finally:
        dr.set_thread_count(n_dr)
    assert runs[0][0] == runs[1][0] and runs[0][1] == runs[1][1]
    assert torch.equal(runs[0][2], runs[1][2])
