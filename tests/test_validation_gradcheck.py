"""AD gradients vs float64 central finite differences on a few grid instances (docs/validation.md)."""
import pytest

import gendr

gc = pytest.importorskip("gendr_validation.gradcheck")


@pytest.fixture(scope="module")
def adapter():
    pytest.importorskip("torch")
    return gc.TorchAdapter()


# 676 exponential+rev+sq|probabilistic and 177 gaussian|aczel_alsina(0.25): regressions of the
# reversed-CDF tail and log(1 − F) precision bugs (their differences did not converge before)
@pytest.mark.parametrize("index", [0, 271, 164, 676, 177])
def test_gradients_match_finite_differences(adapter, index):
    inst = gendr.paper_grid()[index]
    res, _ = gc.check_instance(adapter, inst, params=("vertices_unlit", "camera", "vertex_colors", "tau"))
    bad = [(r.param, r.pixel_mean, r.pixel_max, r.loss_err) for r in res if not r.passed]
    assert not bad, bad
    assert {r.param for r in res} == {"vertices_unlit", "camera", "vertex_colors", "tau"}


class _DropsPart(gc.TorchAdapter):
    """An adapter whose AD misses part of a parameter: the field of view of the camera direction
    (its AD sees azimuth, elevation and distance only), or 0.1 % of the colours' gradient."""

    def loss_grad(self, inst, mesh, cam_params, tau, H, W, weights, param, direction, shading=None):
        if param == "camera":
            direction = [*direction[:3], 0.0]
        g = super().loss_grad(inst, mesh, cam_params, tau, H, W, weights, param, direction, shading)
        return g * 1.001 if param == "vertex_colors" else g

    def per_pixel(self, inst, mesh, cam_params, tau, H, W, param, direction, index, shading=None):
        if param == "camera":
            direction = [*direction[:3], 0.0]
        g = super().per_pixel(inst, mesh, cam_params, tau, H, W, param, direction, index, shading)
        return g * 1.001 if param == "vertex_colors" else g


def test_the_fov_and_colour_checks_can_fail():
    """The camera direction includes fov_y, and colours are checked: an AD that misses either fails."""
    res, _ = gc.check_instance(_DropsPart(), gendr.paper_grid()[271], params=("camera", "vertex_colors"))
    assert [(r.param, r.passed) for r in res] == [("camera", False), ("vertex_colors", False)]


@pytest.mark.parametrize("backend", sorted(set(gc.ADAPTERS) - {"torch"}))
def test_other_backends_gradients(backend):
    from gendr_validation.hardlimit import usable_backends
    if not usable_backends([backend]):
        pytest.skip(f"backend {backend} unavailable")
    res, _ = gc.check_instance(gc.ADAPTERS[backend](), gendr.paper_grid()[271],
                               params=("vertices_unlit", "camera", "vertex_colors", "tau"))
    bad = [(r.param, r.pixel_mean, r.pixel_max, r.loss_err) for r in res if not r.passed]
    assert not bad, bad


def test_lit_vertex_gradients(adapter):
    res, _ = gc.check_instance(adapter, gendr.paper_grid()[271], params=("vertices",))
    assert [r.param for r in res] == ["vertices"]  # one check per parameter asked for: none is vacuous
    assert all(r.passed for r in res), [(r.pixel_max, r.loss_err) for r in res]


def test_instance_selection():
    assert [i.index for i in gc.select_instances("0,271")] == [0, 271]
    assert len(gc.select_instances("quick")) == len(gc.QUICK_NAMES)
    with pytest.raises(gendr.ParameterError):
        gc.select_instances("99999")


#: checks whose loss misses the 1e-5 threshold by FD round-off, not by a wrong gradient
#: (docs/validation.md §6): #444 reciprocal|yager(1), unlit vertices: AD 2.5e-9 vs FD −7.9e-9, a
#: derivative that is zero to round-off; #390 cauchy|yager(1), unlit vertices, since the camera
#: direction moves fov_y too: loss error 1.08e-5 (9.5e-7 at a 10× step). At a 10× step both pass (below)
KNOWN_FD_LIMITED = {(390, "vertices_unlit"), (444, "vertices_unlit")}


@pytest.mark.slow
def test_gradients_all_instances(adapter):
    from gendr_validation.report import _one_thread  # 8x12 renders: a thread pool only costs
    bad = []
    with _one_thread():
        for inst in gc.select_instances("all"):
            res, _ = gc.check_instance(adapter, inst, params=("vertices_unlit", "camera", "tau"))
            bad += [(inst.index, r.param) for r in res if not r.passed]
    assert set(bad) <= KNOWN_FD_LIMITED, bad


@pytest.mark.parametrize("index,param", sorted(KNOWN_FD_LIMITED))
def test_known_fd_limited_checks_pass_at_a_larger_step(adapter, index, param, monkeypatch):
    monkeypatch.setitem(gc.STEPS, param, 10 * gc.STEPS[param])
    res, _ = gc.check_instance(adapter, gendr.paper_grid()[index], params=(param,))
    assert [r.param for r in res] == [param]  # the check ran (an empty list would pass below)
    assert all(r.passed for r in res), [(r.pixel_max, r.loss_err) for r in res]
