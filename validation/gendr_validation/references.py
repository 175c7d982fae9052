"""Independent reference renderers: binary silhouettes and view depth from pyrender and Mitsuba 3.

Both are set up to sample exactly one point per pixel, at the pixel centre (STACK.md):

* pyrender: offscreen, ``PYOPENGL_PLATFORM`` = ``osmesa`` (default, CPU) or ``egl``; the EGL path
  renders into a multisampled buffer by default, so multisampling is switched off; osmesa returns RGB
  only, so the mask is ``depth > 0``; every material is ``doubleSided`` (open meshes show back faces).
* Mitsuba 3 (``scalar_rgb`` or ``llvm_ad_rgb``): stratified sampler without jitter, one sample per
  pixel, box filter, ``fov_axis = 'y'``; the mask is the alpha channel (coverage) of the ``aov``
  integrator, the depth comes from the world position AOV.

Cameras are converted from gendr's conventions (DESIGN.md §3). Lenses a reference cannot express
exactly (pyrender's orthographic camera uses xmag = ymag·W/H; Mitsuba's pinhole has fx = fy) are
matched by stretching the scene along the camera's right axis (see :func:`cameras.stretch_along`).
Rays/fragments nearer than ``near`` are clipped by the plane z = −near in both references, as in
gendr. gendr's ``far`` does not clip, so the references use a far plane of at least 1e4.

Every reference is a :class:`Reference` with ``render(mesh, camera, H, W) -> (mask, depth)``:
``mask`` [H, W] bool, ``depth`` [H, W] float64 positive view depth (0 where empty). A reference
whose package or platform is missing raises :class:`ReferenceUnavailableError`, a subclass of
:class:`gendr.BackendUnavailableError`, with the reason and how to fix it.
"""
from __future__ import annotations

import atexit
import math
import os

import numpy as np

from gendr.errors import BackendUnavailableError

from .cameras import camera_geometry, stretch_along

FAR_MIN = 1e4


class ReferenceUnavailableError(BackendUnavailableError):
    """A reference renderer cannot run here (package, variant or GL platform missing)."""


class Reference:
    name = "reference"

    def render(self, mesh, camera, H: int, W: int):  # pragma: no cover - interface
        raise NotImplementedError

    def close(self):
        pass


# ------------------------------------------------------------------------------------------------
# pyrender
# ------------------------------------------------------------------------------------------------
_PYRENDER = None  # (module, platform) once imported


def _import_pyrender(platform: str):
    global _PYRENDER
    current = os.environ.get("PYOPENGL_PLATFORM")
    if _PYRENDER is not None:
        if _PYRENDER[1] != platform:
            raise ReferenceUnavailableError(
                f"pyrender was already started with PYOPENGL_PLATFORM={_PYRENDER[1]!r} in this process; "
                f"{platform!r} needs a new process (the GL platform cannot change once OpenGL is imported)")
        return _PYRENDER[0]
    import sys
    if "OpenGL" in sys.modules and current != platform:
        raise ReferenceUnavailableError(
            f"OpenGL was imported with PYOPENGL_PLATFORM={current!r} before the pyrender reference "
            f"asked for {platform!r}; run in a fresh process or set PYOPENGL_PLATFORM={platform} first")
    os.environ["PYOPENGL_PLATFORM"] = platform
    try:
        if not hasattr(np, "infty"):  # pyrender 0.1.45 uses np.infty, removed in NumPy 2
            np.infty = np.inf
        import pyrender
    except Exception as e:  # ImportError, or OpenGL failing to find the platform library
        raise ReferenceUnavailableError(
            f"pyrender reference unavailable ({type(e).__name__}: {e}); install the validation extra "
            f"(`pip install gendr[validation]` + `pip install --no-deps pyrender==0.1.45`) and "
            f"libosmesa6 (osmesa) or libegl1 libegl-mesa0 (egl)") from None
    _PYRENDER = (pyrender, platform)
    return pyrender


class PyrenderReference(Reference):
    """pyrender offscreen rasterization (OpenGL pixel-centre sampling, no multisampling)."""

    def __init__(self, platform: str = "osmesa"):
        if platform not in ("osmesa", "egl"):
            raise ReferenceUnavailableError(f"pyrender platform must be 'osmesa' or 'egl', got {platform!r}")
        self.platform = platform
        self.name = f"pyrender-{platform}"
        self.pyrender = _import_pyrender(platform)
        self._renderers = {}
        atexit.register(self.close)
        self._renderer(8, 8)  # a context now: one that cannot be made is unavailable, not a crash mid-run

    def _renderer(self, H, W):
        r = self._renderers.get((H, W))
        if r is None:
            try:
                r = self.pyrender.OffscreenRenderer(W, H)
            except Exception as e:
                raise ReferenceUnavailableError(
                    f"pyrender could not create a {self.platform} context ({type(e).__name__}: {e})") from None
            self._renderers[(H, W)] = r
        return r

    def _camera(self, verts, camera, H, W):
        pr = self.pyrender
        g = camera_geometry(camera)
        far = max(g.far, FAR_MIN)
        if g.kind == "perspective":
            cam = pr.PerspectiveCamera(yfov=math.radians(g.fov_y), aspectRatio=W / H, znear=g.near, zfar=far)
        elif g.kind == "intrinsics":
            cam = pr.IntrinsicsCamera(fx=g.fx, fy=g.fy, cx=g.cx, cy=g.cy, znear=g.near, zfar=far)
        else:
            # pyrender renders with xmag = ymag·W/H whatever xmag says: stretch the scene instead
            verts = stretch_along(verts, g.eye, g.right, (g.ymag * W / H) / g.xmag)
            cam = pr.OrthographicCamera(xmag=g.ymag * W / H, ymag=g.ymag, znear=g.near, zfar=far)
        return g, far, cam, verts

    def render(self, mesh, camera, H, W):
        mask, depth, _ = self._render(mesh, camera, H, W)
        return mask, depth

    def render_textured(self, mesh, camera, H, W, filter="bilinear", wrap="repeat"):
        """(mask [H, W] bool, rgb [H, W, 3] float64 in [0, 1], 8-bit): the unlit texture colour of a
        :class:`gendr.scenes.TexturedMesh` (FLAT shading = base colour × texture, no sRGB
        conversion), sampled by OpenGL with ``filter`` (no mip-maps) and ``wrap``."""
        mask, _, rgb = self._render(mesh, camera, H, W, texture=(filter, wrap))
        return mask, rgb

    def _render(self, mesh, camera, H, W, texture=None):
        pr = self.pyrender
        g, far, cam, verts = self._camera(mesh.vertices, camera, H, W)
        extra = {}
        if texture is None:
            material = pr.MetallicRoughnessMaterial(doubleSided=True, baseColorFactor=(1.0, 1.0, 1.0, 1.0))
            positions, indices = verts, mesh.faces
        else:
            from OpenGL import GL
            flt = GL.GL_LINEAR if texture[0] == "bilinear" else GL.GL_NEAREST
            wrp = GL.GL_REPEAT if texture[1] == "repeat" else GL.GL_CLAMP_TO_EDGE
            img = np.round(np.clip(mesh.texture[..., :3], 0, 1) * 255).astype(np.uint8)
            tex = pr.Texture(source=img, source_channels="RGB",
                             sampler=pr.Sampler(magFilter=flt, minFilter=flt, wrapS=wrp, wrapT=wrp))
            material = pr.MetallicRoughnessMaterial(doubleSided=True, baseColorFactor=(1.0, 1.0, 1.0, 1.0),
                                                    baseColorTexture=tex)
            # one vertex per face corner: uvs are indexed per corner (pyrender uploads the image
            # flipped, so OBJ-convention v = 1 is the image's first row, as in gendr)
            positions, indices = verts[mesh.faces].reshape(-1, 3), np.arange(3 * mesh.num_faces).reshape(-1, 3)
            extra["texcoord_0"] = mesh.corner_uvs().reshape(-1, 2).astype(np.float32)
        prim = pr.Primitive(positions=positions.astype(np.float32), indices=indices.astype(np.uint32),
                            material=material, mode=pr.constants.GLTF.TRIANGLES, **extra)
        scene = pr.Scene(bg_color=(0.0, 0.0, 0.0, 0.0), ambient_light=(1.0, 1.0, 1.0))
        scene.add(pr.Mesh([prim]))
        scene.add(cam, pose=g.pose)
        r = self._renderer(H, W)
        import pyrender.renderer as prr
        original = prr.glRenderbufferStorageMultisample
        # no multisampling: allocate the "multisampled" buffers with 0 samples (one per pixel centre)
        prr.glRenderbufferStorageMultisample = lambda target, samples, fmt, w, h: original(target, 0, fmt, w, h)
        try:
            # not DEPTH_ONLY: pyrender's depth-only pass always culls back faces (renderer.py ignores
            # doubleSided there), which hides open meshes' insides and near-clipped interiors
            color, depth = r.render(scene, flags=pr.RenderFlags.FLAT | pr.RenderFlags.SKIP_CULL_FACES)
            depth = np.array(depth, dtype=np.float64)
            rgb = np.asarray(color, dtype=np.float64)[..., :3] / 255.0
        finally:
            prr.glRenderbufferStorageMultisample = original
        mask = depth > 0
        if g.kind == "orthographic":
            # pyrender linearises with the perspective formula; undo it: z_ndc, then linear depth
            n, f = g.near, far
            zn = np.where(mask, (f + n - 2 * n * f / np.where(mask, depth, 1.0)) / (f - n), 0.0)
            depth = np.where(mask, n + (zn + 1) / 2 * (f - n), 0.0)
        return mask, depth, rgb

    def close(self):
        for r in self._renderers.values():
            try:
                r.delete()
            except Exception:
                pass
        self._renderers.clear()


# ------------------------------------------------------------------------------------------------
# Mitsuba 3
# ------------------------------------------------------------------------------------------------
def _import_mitsuba(variant: str):
    try:
        import mitsuba as mi
    except Exception as e:
        raise ReferenceUnavailableError(
            f"Mitsuba reference unavailable ({type(e).__name__}: {e}); `pip install mitsuba==3.9.1`") from None
    if variant not in mi.variants():
        raise ReferenceUnavailableError(
            f"Mitsuba variant {variant!r} is not available; available: {', '.join(mi.variants())}")
    try:
        mi.set_variant(variant)
    except Exception as e:  # e.g. llvm_ad_rgb without a usable libLLVM
        raise ReferenceUnavailableError(
            f"Mitsuba variant {variant!r} cannot start ({type(e).__name__}: {e}); llvm variants need "
            f"LLVM >= 17 (Debian: libllvm19, DRJIT_LIBLLVM_PATH)") from None
    return mi


class MitsubaReference(Reference):
    """Mitsuba 3 ray tracing with one unjittered sample at each pixel centre and a box filter."""

    def __init__(self, variant: str = "scalar_rgb"):
        self.variant = variant
        self.name = f"mitsuba-{variant}"
        self.mi = _import_mitsuba(variant)

    def render(self, mesh, camera, H, W):
        a = self.render_aovs(mesh, camera, H, W)
        return a["mask"], a["depth"]

    def render_textured(self, mesh, camera, H, W, filter="bilinear", wrap="repeat"):
        """(mask, rgb [H, W, 3] float64): the texture colour of a :class:`gendr.scenes.TexturedMesh`
        at each pixel centre (the ``albedo`` AOV of a diffuse BSDF with a raw float ``bitmap``
        texture, ``filter_type`` = ``filter``, ``wrap_mode`` = ``wrap``)."""
        a = self.render_aovs(mesh, camera, H, W, texture=(filter, wrap))
        return a["mask"], a["albedo"]

    def render_aovs(self, mesh, camera, H, W, texture=None):
        """{"mask", "depth", "face_id" (Mitsuba's prim_index AOV; −1 where empty)} (+ "albedo" with
        a texture) at the pixel centres."""
        mi = self.mi
        mi.set_variant(self.variant)  # another reference may have switched it
        g = camera_geometry(camera)
        verts = mesh.vertices
        far = max(g.far, FAR_MIN)
        T = mi.ScalarTransform4f
        look = T().look_at(origin=g.eye.tolist(), target=(g.eye - g.R[2]).tolist(), up=g.R[1].tolist())
        if g.kind == "orthographic":
            sensor = {"type": "orthographic", "to_world": look @ T().scale([g.xmag, g.ymag * W / H, 1.0])}  # Mitsuba spans x in [-1, 1], y in ±H/W
        else:
            if g.kind == "perspective":
                fov, ppx, ppy = g.fov_y, 0.0, 0.0
            else:
                # pinhole with fy; fx != fy by stretching the scene along the right axis
                fov = math.degrees(2 * math.atan(H / (2 * g.fy)))
                verts = stretch_along(verts, g.eye, g.right, g.fx / g.fy)
                ppx, ppy = (W / 2 - g.cx) / W, (H / 2 - g.cy) / H
            sensor = {"type": "perspective", "fov": fov, "fov_axis": "y", "to_world": look,
                      "principal_point_offset_x": ppx, "principal_point_offset_y": ppy}
        sensor.update(near_clip=g.near, far_clip=far,
                      sampler={"type": "stratified", "sample_count": 1, "jitter": False},
                      film={"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"},
                            "pixel_format": "rgba", "sample_border": False})
        llvm = "llvm" in self.variant
        faces = mesh.faces
        props = mi.Properties()
        if texture is not None:
            # one vertex per face corner (uvs are indexed per corner); Mitsuba's uv has v down
            # (its OBJ loader stores 1 − v), so row 0 of the bitmap is v = 1 as in gendr
            verts, faces = verts[faces].reshape(-1, 3), np.arange(3 * len(faces)).reshape(-1, 3)
            bmp = mi.Bitmap(np.ascontiguousarray(mesh.texture[..., :3], dtype=np.float32))
            props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": {
                "type": "bitmap", "bitmap": bmp, "raw": True, "filter_type": texture[0], "wrap_mode": texture[1]}})
        m = mi.Mesh("m", len(verts), len(faces), props=props, has_vertex_texcoords=texture is not None)
        params = mi.traverse(m)
        params["vertex_positions"] = mi.Float(verts.astype(np.float32).reshape(-1)) if llvm \
            else verts.astype(np.float32).reshape(-1)
        params["faces"] = mi.UInt32(faces.astype(np.uint32).reshape(-1)) if llvm else faces.astype(np.uint32).reshape(-1)
        if texture is not None:
            uv = mesh.corner_uvs().reshape(-1, 2) * np.array([1.0, -1.0]) + np.array([0.0, 1.0])
            uv = uv.astype(np.float32).reshape(-1)
            params["vertex_texcoords"] = mi.Float(uv) if llvm else uv
        params.update()
        aovs = "p:position,pi:prim_index" + (",a:albedo" if texture is not None else "")
        scene = mi.load_dict({"type": "scene", "integrator": {"type": "aov", "aovs": aovs, "inner": {"type": "depth"}},
                              "sensor": sensor, "shape": m})
        img = np.array(mi.render(scene, spp=1), dtype=np.float64)  # [H, W, 4 + 3 + 1 (+ 3)]
        mask = img[..., 3] > 0.5
        pos = img[..., 4:7]
        out = {"mask": mask, "depth": np.where(mask, -g.view(pos)[..., 2], 0.0),
               "face_id": np.where(mask, np.round(img[..., 7]), -1).astype(np.int64)}
        if texture is not None:
            out["albedo"] = np.where(mask[..., None], img[..., 8:11], 0.0)
        return out


REFERENCES = {
    "pyrender": lambda: PyrenderReference("osmesa"),
    "pyrender-osmesa": lambda: PyrenderReference("osmesa"),
    "pyrender-egl": lambda: PyrenderReference("egl"),
    "mitsuba": lambda: MitsubaReference("scalar_rgb"),
    "mitsuba-scalar_rgb": lambda: MitsubaReference("scalar_rgb"),
    "mitsuba-llvm_ad_rgb": lambda: MitsubaReference("llvm_ad_rgb"),
}
DEFAULT_REFERENCES = ("pyrender-osmesa", "mitsuba-scalar_rgb")


def get_reference(name: str) -> Reference:
    """A reference by name (see :data:`REFERENCES`); raises ReferenceUnavailableError if it cannot run."""
    from gendr.errors import UnknownNameError
    if name not in REFERENCES:
        raise UnknownNameError("reference", name, sorted(REFERENCES))
    return REFERENCES[name]()
