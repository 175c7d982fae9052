"""The G-buffer: per-pixel rasterizer output beside the image (like PyTorch3D's ``Fragments`` and
nvdiffrast's ``rasterize``), returned by :meth:`gendr.Renderer.rasterize`."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

__all__ = ["GBuffer"]


@dataclass(frozen=True, eq=False)
class GBuffer:
    """What the hard z-buffer sees at each pixel centre (arrays of the renderer's backend).

    The visible face at a pixel is the nearest face whose (near-clipped) projected polygon contains
    the pixel centre, as for ``blend="hard"``: same containment test (signed distance d >= 0, the
    τ → 0 limit of the soft silhouette), same depth, exact ties to the lowest face index; with
    ``cull_backfaces=True`` only counter-clockwise faces take part. Coverage settings (distribution,
    τ, eps) play no part.

    Attributes:
        face_id: [B, H, W] integer (torch: int64; drjit: int32), index into ``faces`` of the visible
            face, −1 for background. Not differentiable.
        bary: [B, H, W, 3] perspective-correct barycentric coordinates of the pixel centre w.r.t. the
            face's corners (faces[face_id, 0..2]; of the unclipped triangle), summing to 1; 0 on
            background. Differentiable w.r.t. vertices and camera.
        depth: [B, H, W] view depth = −z_view (**positive** in front of the camera; the OpenGL camera
            looks along −Z), world units, the depth the z-buffer compares (clamped to >= near); 0 on
            background. Differentiable.
        normal: [B, H, W, 3] world-space unit normal: the face's area-weighted vertex normals
            interpolated with ``bary``, renormalised (smooth shading normal, as Lambert shading
            uses); 0 on background. Differentiable.

    The floating arrays have the vertices' dtype; all arrays are on the vertices' device (torch
    CPU/CUDA tensors, or Dr.Jit tensors). ``mask`` is ``face_id >= 0``.

    >>> import torch, gendr
    >>> from gendr import scenes
    >>> mesh = scenes.cube()
    >>> r = gendr.Renderer(image_size=8, backend="torch")
    >>> g = r.rasterize(torch.tensor(mesh.vertices, dtype=torch.float32), mesh.faces,
    ...                 gendr.orbit_camera(0.0, 0.0, 3.0))
    >>> g.face_id.shape, g.bary.dtype, g.normal.shape, g.mask.dtype
    (torch.Size([1, 8, 8]), torch.float32, torch.Size([1, 8, 8, 3]), torch.bool)
    >>> n = g.normal[0, 4, 4]  # a unit normal of the +Z side (smooth: interpolated vertex normals)
    >>> round(float(n.norm()), 3), bool(n[2] > 0.9), int(g.face_id[0, 0, 0])  # corner: background
    (1.0, True, -1)
    """

    face_id: Any
    bary: Any
    depth: Any
    normal: Any

    @property
    def mask(self):
        """[B, H, W] bool: a face is visible."""
        return self.face_id >= 0
