"""gendr_experiments.recon: data layout, voxelisation, 3D IoU, training end to end on synthetic data."""
import numpy as np
import pytest
import torch

from gendr import scenes
from gendr_experiments.recon import (NUM_VIEWS, ShapeNetViews, evaluate, make_synthetic_dataset, train, voxel_iou,
                                     voxelize)


@pytest.fixture(scope="module")
def data_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("syn")
    make_synthetic_dataset(d, classes=("airplane", "chair"), objects=(3, 1), image_size=32, seed=0)
    return d


def test_voxelize_sphere_volume_and_union():
    s = scenes.icosphere(3, radius=0.4)
    v = voxelize(s.vertices, s.faces, 32, "xyz")
    assert v.shape == (32, 32, 32)
    expected = 4 / 3 * np.pi * (0.4 * 31 / 32) ** 3  # the SoftRas normalisation shrinks by 31/32
    assert v.mean() == pytest.approx(expected, rel=0.05)
    # two overlapping closed parts: the union (winding number), not the parity (which would carve a hole)
    a = scenes.icosphere(2, radius=0.25)
    both = scenes.concatenate([a, scenes.Mesh(a.vertices + [0.1, 0, 0], a.faces)])
    vb = voxelize(both.vertices, both.faces, 32, "xyz")
    assert vb[16, 16, 16] and vb.sum() > voxelize(a.vertices, a.faces, 32, "xyz").sum()
    # the SoftRas order is a permutation/flip of the same voxels
    assert voxelize(both.vertices, both.faces).sum() == vb.sum()
    assert voxel_iou(vb, vb) == 1.0 and voxel_iou(vb, ~vb) == 0.0


def test_loader_layout(data_dir):
    d = ShapeNetViews(data_dir, ["airplane", "chair"], "train")
    assert len(d) == 6 and d.image_size == 32
    assert d.images.shape == (6, NUM_VIEWS, 4, 32, 32) and d.images.dtype == np.uint8
    assert d.voxels.shape == (6, 32, 32, 32)
    b = d.batch(np.array([0, 5]), np.array([0, 23]))
    assert b.shape == (2, 4, 32, 32) and 0 <= float(b.min()) and float(b.max()) <= 1
    assert float(b[:, 3].mean()) > 0.01  # the objects are visible in the alpha channel
    with pytest.raises(FileNotFoundError):
        ShapeNetViews(data_dir, ["nope"], "train")


def test_recon_trains_and_evaluates(data_dir):
    torch.set_num_threads(1)
    tr = ShapeNetViews(data_dir, ["airplane", "chair"], "train")
    ev = ShapeNetViews(data_dir, ["airplane", "chair"], "val")
    model, hist = train(tr, steps=40, batch_size=4, lr=1e-3, tau=0.02, seed=0)
    loss = np.array(hist["iou_loss"])
    assert np.isfinite(loss).all()
    assert loss[-10:].mean() < loss[:10].mean() - 0.05
    m = evaluate(model, ev, views=[0, 12])
    assert set(m["class_iou"]) == {"airplane", "chair"} and m["evaluated"] == 4
    assert 0.0 <= m["mean_iou"] <= 1.0 and m["mean_iou"] > 0.0
