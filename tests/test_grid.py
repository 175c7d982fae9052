"""The paper's grid: 1,242 instances, each constructs a renderer that renders (finite, in [0, 1])."""
import pytest
import torch

import gendr
from gendr.grid import DISTRIBUTION_SETTINGS, TCONORM_SETTINGS

GRID = gendr.paper_grid()
# two overlapping triangles at different depths, one partly off-screen
VERTS = torch.tensor([[-0.6, -0.5, 0.0], [0.5, -0.4, 0.0], [0.0, 0.6, 0.0],
                      [-0.2, -0.2, 0.3], [0.9, 0.0, 0.3], [0.3, 0.9, 0.3]], dtype=torch.float64)
FACES = torch.tensor([[0, 1, 2], [3, 4, 5]])
CAMERA = gendr.PerspectiveCamera(eye=(0.0, 0.0, 3.0), fov_y=40.0)


def test_grid_size_and_structure():
    assert len(DISTRIBUTION_SETTINGS) == 23 and len(TCONORM_SETTINGS) == 27
    assert len(GRID) == 23 * 2 * 27 == 1242
    assert len({inst.name for inst in GRID}) == 1242, "instance names must be unique"
    assert [inst.index for inst in GRID] == list(range(1242))
    assert sum(inst.distribution.squared for inst in GRID) == 621


@pytest.mark.parametrize("chunk", range(0, 1242, 138), ids=lambda c: f"instances{c}-{c + 137}")
def test_every_instance_renders(chunk):
    for inst in GRID[chunk:chunk + 138]:
        squared = inst.distribution.squared
        # inside distances reach ~0.25 screen units: τ small enough that one-sided distributions
        # (gamma shape 5, levy) cover the interior; squared variants take τ in squared units
        tau = 0.004 if squared else 0.02
        r = gendr.Renderer(inst.distribution, inst.tconorm, tau=tau, image_size=(8, 9), eps=1e-3, blend=None)
        v = VERTS.clone().requires_grad_(True)
        img = r.render(v, FACES, CAMERA)
        alpha = img[0, ..., 3]
        assert img.shape == (1, 8, 9, 4), inst.name
        assert torch.isfinite(img).all(), inst.name
        alpha_values = alpha.detach()
        assert float(alpha_values.min()) >= 0.0 and float(alpha_values.max()) <= 1.0 + 1e-12, inst.name
        assert float(alpha_values.max()) > 0.4, f"{inst.name}: nothing covered"
        alpha.sum().backward()
        assert torch.isfinite(v.grad).all(), inst.name
