"""Textures and G-buffers vs the reference renderers, pixel by pixel (docs/validation.md §5).

* **Textures**: gendr's hard-blend RGB of a textured scene, unlit (ambient 1, diffuse 0: the colour
  is the sampled texture), vs Mitsuba 3's albedo AOV of a raw bitmap texture and pyrender's FLAT
  (unlit) shading, with the same texture, filter and wrap mode. Compared where gendr and the
  reference both see the mesh and the pixel is unambiguous: its centre at least δ from every
  projected edge (as in the hard-limit check, :data:`hardlimit.AMBIGUITY_PX`), and for ``nearest``
  its texel coordinates at least :data:`TEXEL_AMBIGUITY` texels from a texel boundary (the texel is
  a discontinuous function of uv there; computed from gendr's G-buffer). A pixel differs when
  max |Δrgb| > :data:`TOLERANCE` for its (reference, filter); the target is 0.
* **G-buffers**: :meth:`gendr.Renderer.rasterize` on the scenes × cameras of the hard-limit check:
  its mask (face_id ≥ 0) vs each reference's mask, its depth vs the reference depth (relative
  tolerance :data:`DEPTH_RTOL`, plus pyrender's depth-buffer quantisation), its face ids vs
  Mitsuba's ``prim_index`` AOV (exact, coincident faces identified: :func:`canonical_face_ids`), on
  the unambiguous pixels.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

import gendr

from .cameras import camera_geometry, edge_distance
from .hardlimit import ambiguity_px

#: max |Δrgb| allowed on an unambiguous pixel, per (reference kind, filter). Why:
#: Mitsuba stores the texture in float32 and intersects in float32: uv errors ~1e-6 times texture
#: slopes up to ~30 per uv unit (a full checker step per texel at 32 texels) stay below 1e-4 (5.5e-5
#: measured on the textured cube); nearest reads one float32 texel (3e-8 measured).
#: pyrender returns 8-bit colour (±0.5/255) and Mesa's llvmpipe filters with 8-bit fixed-point
#: bilinear weights (a further ≤ 1/256 of a texel step, ≤ 1): 2/255 (4.5e-3 = 1.15/255 measured);
#: its nearest reads the exact 8-bit texel (textures are multiples of 1/255): exact.
TOLERANCE = {("mitsuba", "bilinear"): 2e-4, ("mitsuba", "nearest"): 1e-6,
             ("pyrender", "bilinear"): 2.0 / 255.0, ("pyrender", "nearest"): 1e-6}
#: nearest filter: pixels whose texel coordinates lie within this many texels of a texel boundary
#: are ambiguous (float32 uv interpolation in both references; Mesa snaps texel coordinates to 1/256)
TEXEL_AMBIGUITY = {"mitsuba": 1e-3, "pyrender": 1.0 / 256.0}
#: G-buffer depth: |ours − ref| <= DEPTH_RTOL·ref (float32 geometry in both references: 1e-5
#: relative measured vs Mitsuba) + for pyrender DEPTH_STEPS steps of its 24-bit depth buffer (window
#: depth d in [0, 1] with far = 1e4: a step is 2⁻²⁴·(far − near) ≈ 6e-4 world units for orthographic
#: cameras, 2⁻²⁴·z²(far − near)/(far·near) ≈ 5e-6 at z = 3 for perspective ones)
DEPTH_RTOL = 1e-4
DEPTH_STEPS = 4
FILTERS = ("bilinear", "nearest")
TEXTURED_QUICK_CAMERAS = ("perspective", "orthographic", "intrinsics", "perspective_near")


def _kind(reference_name):
    return "pyrender" if reference_name.startswith("pyrender") else "mitsuba"


@dataclass
class TextureResult:
    scene: str
    camera: str
    backend: str
    reference: str
    filter: str
    compared: int          # unambiguous pixels both see
    ambiguous: int         # covered pixels left out (edges; texel boundaries for nearest)
    differ: int            # compared pixels with max |Δrgb| > tolerance
    max_abs_diff: float    # over the compared pixels
    tolerance: float
    seconds: float
    error: str = ""

    @property
    def passed(self) -> bool:
        return not self.error and self.differ == 0


@dataclass
class GBufferResult:
    scene: str
    camera: str
    backend: str
    reference: str
    pixels: int
    ambiguous: int
    mask_differ: int       # unambiguous pixels where face_id >= 0 disagrees with the reference mask
    depth_differ: int      # unambiguous pixels both cover with |Δdepth| > DEPTH_RTOL·depth
    depth_max_rel: float
    face_id_differ: int    # unambiguous pixels with another face id (-1: the reference has none)
    seconds: float
    error: str = ""

    @property
    def passed(self) -> bool:
        return not self.error and self.mask_differ == 0 and self.depth_differ == 0 and self.face_id_differ <= 0


def _numpy(r, x):
    return np.asarray(r.to_numpy(x))


def texel_boundary_distance(mesh, gbuf_face_id, gbuf_bary, filt="nearest"):
    """Per pixel: the distance, in texels, of its texel coordinates to the nearest texel boundary
    (nearest filter: the texel index jumps there); inf on background."""
    fid = gbuf_face_id
    uv = (gbuf_bary[..., None] * mesh.corner_uvs()[np.maximum(fid, 0)]).sum(-2)
    Ht, Wt = mesh.texture.shape[:2]
    x, y = uv[..., 0] * Wt, (1.0 - uv[..., 1]) * Ht
    dist = np.minimum(np.abs(x - np.round(x)), np.abs(y - np.round(y)))
    return np.where(fid >= 0, dist, np.inf)


def check_textures(scene_name, mesh, camera_name, camera, H, W, backends, references, filters=FILTERS):
    """[TextureResult] for one textured scene × camera, every backend × reference × filter."""
    out = []
    edist = edge_distance(mesh, camera_geometry(camera), H, W)
    for filt in filters:
        refs = {n: ref.render_textured(mesh, camera, H, W, filt) for n, ref in references.items()}
        for b in backends:
            t0 = time.perf_counter()
            try:
                r = gendr.Renderer("heaviside", "or", tau=1.0, image_size=(H, W), backend=b, blend="hard",
                                   ambient=1.0, diffuse=0.0, texture_filter=filt)
                img = _numpy(r, r.render(mesh.vertices, mesh.faces, camera, texture=mesh.texture, uvs=mesh.uvs,
                                         uv_faces=mesh.uv_faces))[0]
                g = r.rasterize(mesh.vertices, mesh.faces, camera)
                fid, bary = _numpy(r, g.face_id)[0], _numpy(r, g.bary)[0]
            except Exception as e:  # a backend bug must not stop the run
                for n in refs:
                    out.append(TextureResult(scene_name, camera_name, b, n, filt, 0, 0, -1, float("nan"),
                                             TOLERANCE[(_kind(n), filt)], time.perf_counter() - t0,
                                             f"{type(e).__name__}: {e}"[:300]))
                continue
            dt = time.perf_counter() - t0
            ours = fid >= 0
            tdist = texel_boundary_distance(mesh, fid, bary) if filt == "nearest" else None
            for n, (mask, rgb) in refs.items():
                amb = edist < ambiguity_px(n)
                if tdist is not None:
                    amb = amb | (tdist < TEXEL_AMBIGUITY[_kind(n)])
                both = ours & mask
                sel = both & ~amb
                d = np.abs(img[..., :3] - rgb).max(-1)
                tol = TOLERANCE[(_kind(n), filt)]
                out.append(TextureResult(scene_name, camera_name, b, n, filt, int(sel.sum()), int((both & amb).sum()),
                                         int((d[sel] > tol).sum()), float(d[sel].max()) if sel.any() else 0.0, tol, dt))
    return out


def canonical_face_ids(mesh):
    """[F] the lowest index of a face with the same three corner positions (coincident faces are
    indistinguishable: gendr breaks their exact depth ties by the lowest index, Mitsuba by BVH order)."""
    first, out = {}, np.empty(mesh.num_faces, dtype=np.int64)
    for i, f in enumerate(mesh.faces):
        key = tuple(sorted(tuple(mesh.vertices[k]) for k in f))
        out[i] = first.setdefault(key, i)
    return out


def depth_tolerance(reference_name, camera, depth):
    """Per pixel allowed |Δdepth| (see DEPTH_RTOL, DEPTH_STEPS)."""
    tol = DEPTH_RTOL * depth
    if _kind(reference_name) == "pyrender":
        from .references import FAR_MIN
        g = camera_geometry(camera)
        n, f = g.near, max(g.far, FAR_MIN)
        dzdd = (f - n) if g.kind == "orthographic" else depth ** 2 * (f - n) / (f * n)
        tol = tol + DEPTH_STEPS * 2.0 ** -24 * dzdd
    return tol


def check_gbuffer(scene_name, mesh, camera_name, camera, H, W, backends, references, ref_images=None, edist=None):
    """[GBufferResult] for one scene × camera. ``ref_images``: {reference: (mask, depth)} already
    rendered (the hard-limit check's), else rendered here; Mitsuba's face ids are always rendered.
    ``edist``: the pixels' distances to the projected edges (computed here when None)."""
    out = []
    if edist is None:
        edist = edge_distance(mesh, camera_geometry(camera), H, W)
    canon = canonical_face_ids(mesh)
    refs = {}
    for n, ref in references.items():
        if _kind(n) == "mitsuba" and hasattr(ref, "render_aovs"):
            a = ref.render_aovs(mesh, camera, H, W)
            refs[n] = (a["mask"], a["depth"], a["face_id"])
        else:
            mask, depth = (ref_images or {}).get(n) or ref.render(mesh, camera, H, W)
            refs[n] = (mask, depth, None)
    for b in backends:
        t0 = time.perf_counter()
        try:
            r = gendr.Renderer("heaviside", "or", tau=1.0, image_size=(H, W), backend=b, blend=None)
            g = r.rasterize(np.ascontiguousarray(mesh.vertices), mesh.faces, camera)
            fid, depth = _numpy(r, g.face_id)[0], _numpy(r, g.depth)[0]
        except Exception as e:
            for n in refs:
                out.append(GBufferResult(scene_name, camera_name, b, n, H * W, 0, -1, -1, float("nan"), -1,
                                         time.perf_counter() - t0, f"{type(e).__name__}: {e}"[:300]))
            continue
        dt = time.perf_counter() - t0
        ours = fid >= 0
        for n, (mask, rdepth, rfid) in refs.items():
            unamb = edist >= ambiguity_px(n)
            both = ours & mask & unamb
            err = np.abs(depth - rdepth)
            rel = err / np.maximum(rdepth, 1e-12)
            bad_depth = err > depth_tolerance(n, camera, rdepth)
            if rfid is None:
                fdiff = -1
            else:
                a, c = (np.where(x >= 0, canon[np.maximum(x, 0)], -1) for x in (fid, rfid))
                fdiff = int(((a != c) & unamb).sum())
            out.append(GBufferResult(scene_name, camera_name, b, n, H * W, int((~unamb).sum()),
                                     int(((ours != mask) & unamb).sum()), int((bad_depth & both).sum()),
                                     float(rel[both].max()) if both.any() else 0.0, fdiff, dt))
    return out
