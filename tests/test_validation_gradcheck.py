"""AD gradients vs float64 central finite differences on a few grid instances (docs/validation.md)."""
import pytest

import gendr

gc = pytest.importorskip("gendr_validation.gradcheck")


@pytest.fixture(scope="module")
def adapter():
    pytest.importorskip("torch")
    return gc.TorchAdapter()


@pytest.mark.parametrize("index", [0, 271, 164])
def test_gradients_match_finite_differences(adapter, index):
    inst = gendr.paper_grid()[index]
    res, _ = gc.check_instance(adapter, inst, params=("vertices_unlit", "camera", "tau"))
    bad = [(r.param, r.pixel_mean, r.pixel_max, r.loss_err) for r in res if not r.passed]
    assert not bad, bad


@pytest.mark.parametrize("backend", sorted(set(gc.ADAPTERS) - {"torch"}))
def test_other_backends_gradients(backend):
    from gendr_validation.hardlimit import usable_backends
    if not usable_backends([backend]):
        pytest.skip(f"backend {backend} unavailable")
    res, _ = gc.check_instance(gc.ADAPTERS[backend](), gendr.paper_grid()[271], params=("vertices_unlit", "camera", "tau"))
    bad = [(r.param, r.pixel_mean, r.pixel_max, r.loss_err) for r in res if not r.passed]
    assert not bad, bad


def test_lit_vertex_gradients(adapter):
    res, _ = gc.check_instance(adapter, gendr.paper_grid()[271], params=("vertices",))
    assert all(r.passed for r in res), [(r.pixel_max, r.loss_err) for r in res]


def test_instance_selection():
    assert [i.index for i in gc.select_instances("0,271")] == [0, 271]
    assert len(gc.select_instances("quick")) == len(gc.QUICK_NAMES)
    with pytest.raises(gendr.ParameterError):
        gc.select_instances("99999")


@pytest.mark.slow
def test_gradients_all_instances(adapter):
    bad = []
    for inst in gc.select_instances("all"):
        res, _ = gc.check_instance(adapter, inst, params=("vertices_unlit", "camera", "tau"))
        bad += [(inst.index, r.param, r.pixel_max, r.loss_err) for r in res if not r.passed]
    assert not bad, bad
