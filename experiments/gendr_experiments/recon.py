"""Single-view 3D reconstruction (paper §5.3) on the N3MR/SoftRas data layout.

Data layout (as distributed with N3MR and SoftRas; one pair of files per class and split)::

    DIR/{class_id}_{split}_images.npz   one array [N, 24, 4, S, S] uint8 (RGBA, S = 64 in the real data)
    DIR/{class_id}_{split}_voxels.npz   one array [N, 32, 32, 32] (occupancy, 0/1)

view ``k`` of an object is seen from elevation 30°, distance 2.732, SoftRas azimuth −15·k (its
``get_points_from_angles``), i.e. gendr ``orbit_camera(180 + 15·k, 30, 2.732, fov_y=60)`` (SoftRas'
``viewing_angle=30`` is the half angle). Objects lie in [−0.5, 0.5]³.

Model (SoftRas' ``Model``, smaller by default): a CNN encoder of the RGBA image and an MLP decoder
predicting bounded displacements of an icosphere template plus a centre offset (the same
parameterisation as :mod:`.shape`). Training: for a random object and two random views a, b, the
mesh predicted from image a is rendered from a and b with any gendr instance; loss = soft IoU loss on
both silhouettes + λ_lap·Laplacian + λ_flat·flatten. Evaluation: the predicted mesh of every view
image is voxelised (32³, the SoftRas normalisation ``p·31/32 + 0.5``) and compared with the class's
voxels: class-wise mean 3D IoU.

**Conventions to verify on the real data** (they are taken from SoftRas' code, not checked against
the real files here, which are not downloaded): the view camera and the voxel axis order
(``voxel_order``). No command checks them yet (an earlier version of this text promised a
``--check-data`` option that was never built): render an object's 24 views with :func:`view_camera`
and compare them with the data's alpha before trusting IoUs on the real data.
"""
from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np
import torch

import gendr
from gendr.errors import ParameterError
from gendr.scenes import icosphere

from .common import (flatten_edges, flatten_loss, instance_from_config, iou_loss_per_view, laplacian_loss,
                     mesh_laplacian, renderer_tau)

__all__ = ["ShapeNetViews", "view_camera", "voxelize", "voxel_iou", "ReconModel", "train", "evaluate",
           "make_synthetic_dataset", "RECON_DEFAULTS"]

ELEVATION, DISTANCE, FOV_Y, NUM_VIEWS = 30.0, 2.732, 60.0, 24

RECON_DEFAULTS = dict(
    distribution="logistic", tconorm="probabilistic", instance=None, tau=0.01, eps=1e-4, backend="torch",
    lr=1e-4, batch_size=8, steps=1000, subdivisions=2, lambda_lap=0.005, lambda_flat=0.0005,
    encoder_width=32, latent=256, seed=0, render_size=None, device="cpu",
)


def view_camera(view_ids, device=None):
    """The dataset's camera for view indices ``view_ids`` ([B] ints): azimuth 180 + 15·k (gendr's
    orbit: azimuth 0 looks from +Z), elevation 30°, distance 2.732, fov_y 60°."""
    az = 180.0 + 15.0 * torch.as_tensor(view_ids, dtype=torch.float32, device=device)
    return gendr.orbit_camera(az, ELEVATION, DISTANCE, fov_y=FOV_Y)


# ------------------------------------------------------------------------------------------------
# data
# ------------------------------------------------------------------------------------------------

def _load_npz_array(path):
    with np.load(path) as z:
        return z[list(z.keys())[0]]


class ShapeNetViews:
    """The N3MR/SoftRas data of some classes and one split (``train``, ``val`` or ``test``)."""

    def __init__(self, directory, class_ids, split):
        self.directory, self.split = Path(directory), split
        self.class_ids = list(class_ids)
        self.images, self.voxels, self.class_of = [], [], []
        for c in self.class_ids:
            im = _load_npz_array(self.directory / f"{c}_{split}_images.npz")
            vx = _load_npz_array(self.directory / f"{c}_{split}_voxels.npz")
            if im.ndim == 4:  # [N*24, 4, S, S]
                im = im.reshape(-1, NUM_VIEWS, *im.shape[1:])
            if im.ndim != 5 or im.shape[1] != NUM_VIEWS or im.shape[2] != 4:
                raise ValueError(f"{c}_{split}_images.npz: expected [N, 24, 4, S, S], got {im.shape}")
            if vx.shape[0] != im.shape[0]:
                raise ValueError(f"class {c}: {im.shape[0]} objects in the images but {vx.shape[0]} in the voxels")
            self.images.append(im)
            self.voxels.append(vx)
            self.class_of += [c] * im.shape[0]
        self.images = np.concatenate(self.images)
        self.voxels = np.concatenate(self.voxels)
        self.class_of = np.array(self.class_of)

    def __len__(self):
        return len(self.images)

    @property
    def image_size(self):
        return int(self.images.shape[-1])

    def batch(self, object_ids, view_ids):
        """``[B, 4, S, S]`` float images in [0, 1] of (object, view) pairs."""
        return torch.from_numpy(self.images[object_ids, view_ids].astype(np.float32) / 255.0)

    def random_batch(self, rng, batch_size):
        obj = rng.integers(0, len(self), batch_size)
        va = rng.integers(0, NUM_VIEWS, batch_size)
        vb = rng.integers(0, NUM_VIEWS, batch_size)
        return obj, va, vb, self.batch(obj, va), self.batch(obj, vb)


# ------------------------------------------------------------------------------------------------
# voxelisation and 3D IoU
# ------------------------------------------------------------------------------------------------

def voxelize(vertices, faces, res: int = 32, voxel_order: str = "softras") -> np.ndarray:
    """Solid ``[res]³`` occupancy of a closed, outward-oriented mesh in [−0.5, 0.5]³.

    Points are normalised as SoftRas' evaluation does (``p·(res−1)/res + 0.5`` in [0, 1]); voxel
    (i, j, k) is inside where the ray from its centre along +z has a non-zero winding number (the
    sum of ±1 over the faces it crosses, signed by the faces' z normal): unions of overlapping closed
    parts come out right. ``voxel_order="softras"`` returns SoftRas' axis order (its
    ``transpose(0, 2, 1, 3)[..., ::-1]`` of [x, y, z]), ``"xyz"`` indexes [x, y, z].
    """
    v = np.asarray(vertices, dtype=np.float64) * ((res - 1) / res) + 0.5
    t = v[np.asarray(faces)]  # [F, 3, 3]
    c = (np.arange(res) + 0.5) / res
    X, Y = np.meshgrid(c, c, indexing="ij")
    px, py = X.reshape(-1, 1), Y.reshape(-1, 1)  # [P, 1]
    a, b, cc = t[:, 0], t[:, 1], t[:, 2]
    # 2D barycentrics of each column centre in each face's xy projection
    d = (b[:, 1] - cc[:, 1]) * (a[:, 0] - cc[:, 0]) + (cc[:, 0] - b[:, 0]) * (a[:, 1] - cc[:, 1])  # [F]
    ok = np.abs(d) > 1e-15
    d = np.where(ok, d, 1.0)
    l0 = ((b[:, 1] - cc[:, 1]) * (px - cc[:, 0]) + (cc[:, 0] - b[:, 0]) * (py - cc[:, 1])) / d
    l1 = ((cc[:, 1] - a[:, 1]) * (px - cc[:, 0]) + (a[:, 0] - cc[:, 0]) * (py - cc[:, 1])) / d
    l2 = 1.0 - l0 - l1
    hit = ok & (l0 >= 0) & (l1 >= 0) & (l2 >= 0)  # [P, F]
    z = l0 * a[:, 2] + l1 * b[:, 2] + l2 * cc[:, 2]
    sign = np.sign(d)  # z component of the face normal: + facing +z
    occ = np.zeros((res * res, res), dtype=bool)
    for k, zc in enumerate(c):
        # faces crossed above the voxel centre: exiting (+) minus entering (−)
        w = (np.where(hit & (z > zc), sign, 0.0)).sum(1)
        occ[:, k] = np.abs(w) > 0.5
    vox = occ.reshape(res, res, res)
    if voxel_order == "softras":
        return np.ascontiguousarray(vox.transpose(1, 0, 2)[:, :, ::-1])
    if voxel_order == "xyz":
        return vox
    raise ValueError(f"voxel_order must be 'softras' or 'xyz', got {voxel_order!r}")


def voxel_iou(a, b) -> float:
    """3D IoU of two boolean occupancy grids (1 where both are empty)."""
    a, b = np.asarray(a) > 0.5, np.asarray(b) > 0.5
    u = np.logical_or(a, b).sum()
    return float(np.logical_and(a, b).sum() / u) if u else 1.0


# ------------------------------------------------------------------------------------------------
# model
# ------------------------------------------------------------------------------------------------

class ReconModel(torch.nn.Module):
    """CNN encoder of a ``[B, 4, S, S]`` image -> latent -> MLP decoder -> ``[B, V, 3]`` vertices of a
    deformed icosphere (SoftRas' bounded displacement + centre parameterisation)."""

    def __init__(self, image_size=64, subdivisions=2, width=32, latent=256):
        super().__init__()
        w = width
        layers, ch, s = [], 4, image_size
        for out in (w, 2 * w, 4 * w):
            layers += [torch.nn.Conv2d(ch, out, 5, stride=2, padding=2), torch.nn.BatchNorm2d(out), torch.nn.ReLU()]
            ch, s = out, (s + 1) // 2
        self.encoder = torch.nn.Sequential(*layers, torch.nn.Flatten(), torch.nn.Linear(ch * s * s, latent),
                                           torch.nn.ReLU())
        sph = icosphere(subdivisions, radius=0.5)
        v0 = torch.tensor(sph.vertices, dtype=torch.float32)
        self.register_buffer("faces", torch.tensor(sph.faces))
        self.register_buffer("base", torch.log(v0.abs() / (1 - v0.abs())))
        self.register_buffer("sign", torch.sign(v0))
        self.faces_np = sph.faces
        V = v0.shape[0]
        self.decoder = torch.nn.Sequential(torch.nn.Linear(latent, 2 * latent), torch.nn.ReLU(),
                                           torch.nn.Linear(2 * latent, V * 3 + 3))
        torch.nn.init.zeros_(self.decoder[-1].weight)
        torch.nn.init.zeros_(self.decoder[-1].bias)

    def forward(self, images):
        h = self.decoder(self.encoder(images))
        B = h.shape[0]
        disp, centre = h[:, :-3].reshape(B, -1, 3), torch.tanh(h[:, -3:]).reshape(B, 1, 3) * 0.5
        v = torch.sigmoid(self.base + disp) * self.sign
        v = torch.relu(v) * (1 - centre) - torch.relu(-v) * (1 + centre)
        return v + centre


def _cfg(config, overrides):
    cfg = dict(RECON_DEFAULTS)
    cfg.update(config or {})
    cfg.update(overrides)
    return cfg


def train(data: ShapeNetViews, config=None, *, log=None, eval_data=None, **overrides):
    """Train a :class:`ReconModel` for ``steps`` steps; returns ``(model, history)`` with the loss of
    every step in ``history["loss"]``."""
    cfg = _cfg(config, overrides)
    torch.manual_seed(int(cfg["seed"]))
    rng = np.random.default_rng(int(cfg["seed"]))
    dev = torch.device(cfg["device"])
    S = data.image_size
    rs = int(cfg["render_size"] or S)
    model = ReconModel(S, int(cfg["subdivisions"]), int(cfg["encoder_width"]), int(cfg["latent"])).to(dev)
    dist, tcn, label = instance_from_config(cfg)
    renderer = gendr.Renderer(dist, tcn, tau=renderer_tau(cfg["tau"], dist.squared), image_size=rs,
                              backend=cfg["backend"], eps=float(cfg["eps"]), blend=None)
    L = mesh_laplacian(model.base.shape[0], model.faces_np).to(dev)
    fe = tuple(x.to(dev) for x in flatten_edges(model.faces_np))
    opt = torch.optim.Adam(model.parameters(), lr=float(cfg["lr"]), betas=(0.5, 0.999))
    hist = {"loss": [], "iou_loss": [], "instance": label, "seconds": 0.0}
    t0 = time.perf_counter()
    for step in range(int(cfg["steps"])):
        model.train()
        _, va, vb, ia, ib = data.random_batch(rng, int(cfg["batch_size"]))
        ia, ib = ia.to(dev), ib.to(dev)
        verts = model(ia)
        views = torch.cat([torch.as_tensor(va), torch.as_tensor(vb)])
        sil = renderer.render(torch.cat([verts, verts]), model.faces, view_camera(views, dev))[..., 3]
        tgt = torch.cat([ia[:, 3], ib[:, 3]])
        if rs != S:
            tgt = torch.nn.functional.adaptive_avg_pool2d(tgt[:, None], rs)[:, 0]
        iou = iou_loss_per_view(sil, tgt).mean()
        loss = iou + cfg["lambda_lap"] * laplacian_loss(verts, L) + cfg["lambda_flat"] * flatten_loss(verts, fe)
        opt.zero_grad()
        loss.backward()
        opt.step()
        hist["loss"].append(float(loss.detach()))
        hist["iou_loss"].append(float(iou.detach()))
        if log and (step % max(1, int(cfg["steps"]) // 20) == 0 or step == int(cfg["steps"]) - 1):
            log(f"step {step}: loss {hist['loss'][-1]:.4f} (iou {hist['iou_loss'][-1]:.4f}) {time.perf_counter() - t0:.1f} s")
    hist["seconds"] = time.perf_counter() - t0
    return model, hist


@torch.no_grad()
def evaluate(model: ReconModel, data: ShapeNetViews, *, views=None, voxel_order="softras", batch_size=32) -> dict:
    """Class-wise mean 3D IoU: every (object, view) image -> predicted mesh -> 32³ voxels vs the
    object's voxels. ``views``: the view indices used (default all 24)."""
    model.eval()
    dev = next(model.parameters()).device
    views = list(range(NUM_VIEWS)) if views is None else list(views)
    pairs = [(o, v) for o in range(len(data)) for v in views]
    per_class = {}
    for i in range(0, len(pairs), batch_size):
        chunk = pairs[i:i + batch_size]
        obj = np.array([p[0] for p in chunk])
        vv = np.array([p[1] for p in chunk])
        verts = model(data.batch(obj, vv).to(dev)).cpu().numpy()
        for o, v in zip(obj, verts):
            iou = voxel_iou(voxelize(v, model.faces_np, data.voxels.shape[-1], voxel_order), data.voxels[o])
            per_class.setdefault(str(data.class_of[o]), []).append(iou)
    out = {c: float(np.mean(x)) for c, x in per_class.items()}
    return {"class_iou": out, "mean_iou": float(np.mean(list(out.values()))) if out else float("nan"),
            "evaluated": len(pairs)}


# ------------------------------------------------------------------------------------------------
# a synthetic data set in the same layout (for tests and smoke runs; no downloads)
# ------------------------------------------------------------------------------------------------

def make_synthetic_dataset(directory, *, classes=("airplane", "chair"), objects=(6, 2), image_size=64,
                           res=32, seed=0, splits=("train", "val")) -> list[str]:
    """Write ``{class}_{split}_images.npz`` / ``_voxels.npz`` of randomly scaled and stretched
    built-in shapes (scaled into [−0.5, 0.5]³), rendered with the hard renderer and Lambert shading
    from the 24 dataset views. Class ids are the scene names. Returns the class ids."""
    from gendr import scenes
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    r = gendr.Renderer("heaviside", "or", tau=1.0, image_size=image_size, eps=0.0, blend="hard",
                       background=(0.0, 0.0, 0.0))
    cam = view_camera(torch.arange(NUM_VIEWS))
    for cls in classes:
        base = scenes.get_scene(cls)
        for split, n in zip(splits, objects):
            ims, vox = [], []
            for _ in range(n):
                s = rng.uniform(0.8, 1.2, size=3)
                v = base.vertices * s
                v = v / np.abs(v).max() * 0.45  # inside [-0.45, 0.45]^3
                img = r.render(torch.tensor(v, dtype=torch.float32), torch.tensor(base.faces), cam)
                ims.append((img.clamp(0, 1).permute(0, 3, 1, 2).numpy() * 255 + 0.5).astype(np.uint8))
                vox.append(voxelize(v, base.faces, res))
            np.savez_compressed(directory / f"{cls}_{split}_images.npz", np.stack(ims))
            np.savez_compressed(directory / f"{cls}_{split}_voxels.npz", np.stack(vox).astype(np.uint8))
    return list(classes)


# ------------------------------------------------------------------------------------------------
# command line
# ------------------------------------------------------------------------------------------------

#: default classes of --data (ShapeNet ids: airplane, chair) and of --synthetic (built-in scenes)
DATA_CLASSES, SYNTHETIC_CLASSES = "02691156,03001627", "airplane,chair"


def classes_of(a) -> list[str]:
    """The class ids the command uses: --classes, else the default of --data or --synthetic."""
    return (a.classes or (SYNTHETIC_CLASSES if a.synthetic else DATA_CLASSES)).split(",")


def add_arguments(p):
    p.description = ("Train the single-view reconstruction model on the N3MR/SoftRas data (DIR/{class}_{split}_"
                     "images.npz, _voxels.npz) with any gendr instance; report class-wise 3D IoU.")
    p.add_argument("--data", default=None, metavar="DIR", help="data directory (N3MR/SoftRas layout)")
    p.add_argument("--synthetic", action="store_true", help="generate a small synthetic data set from built-in "
                                                            "shapes into OUTDIR/data and use it")
    p.add_argument("--classes", default=None,
                   help=f"comma-separated class ids (default: with --data {DATA_CLASSES}, ShapeNet's airplane and "
                        f"chair; with --synthetic {SYNTHETIC_CLASSES}, built-in scene names)")
    p.add_argument("--train-split", default="train")
    p.add_argument("--eval-split", default="val")
    p.add_argument("-o", "--output", default="recon_out", help="output directory (model, history, metrics)")
    for k in ("distribution", "tconorm"):
        p.add_argument(f"--{k}", default=RECON_DEFAULTS[k])
    p.add_argument("--instance", type=int, default=None, help="grid instance (overrides the two above)")
    p.add_argument("--tau", type=float, default=RECON_DEFAULTS["tau"], help="blur width (squared: tau**2)")
    p.add_argument("--lr", type=float, default=RECON_DEFAULTS["lr"])
    p.add_argument("--batch-size", type=int, default=RECON_DEFAULTS["batch_size"])
    p.add_argument("--steps", type=int, default=RECON_DEFAULTS["steps"])
    p.add_argument("--subdivisions", type=int, default=RECON_DEFAULTS["subdivisions"])
    p.add_argument("--render-size", type=int, default=None, help="silhouette size for the loss (default: data's)")
    p.add_argument("--eval-views", default=None, help="comma-separated view ids to evaluate (default all 24)")
    p.add_argument("--voxel-order", choices=("softras", "xyz"), default="softras")
    p.add_argument("--device", default="cpu", help="torch device, e.g. cuda")
    p.add_argument("--backend", default="torch")
    p.add_argument("--seed", type=int, default=0)


def check_cli(a) -> None:
    """The options' values, checked before anything is written or trained (ParameterError naming
    the first bad one; a CUDA device this torch lacks: BackendUnavailableError)."""
    from gendr_torch.backend import torch_device
    if a.synthetic == bool(a.data):
        raise ParameterError("give exactly one of --data DIR and --synthetic")
    if a.data and not Path(a.data).is_dir():
        raise ParameterError(f"--data {a.data!r} is not a directory")
    classes = classes_of(a)
    if not all(classes):
        raise ParameterError(f"--classes {a.classes!r}: an empty class id")
    if a.synthetic:
        from gendr.scenes import SCENES
        bad = [c for c in classes if c not in SCENES]
        if bad:
            raise ParameterError(f"--classes {bad}: --synthetic makes its classes from built-in scenes "
                                 f"({', '.join(sorted(SCENES))})")
        if {a.train_split, a.eval_split} - {"train", "val"}:
            raise ParameterError(f"--synthetic makes the splits train and val, not "
                                 f"{sorted({a.train_split, a.eval_split} - {'train', 'val'})}")
    else:
        missing = [f"{c}_{s}_{kind}.npz" for c in classes for s in dict.fromkeys((a.train_split, a.eval_split))
                   for kind in ("images", "voxels") if not (Path(a.data) / f"{c}_{s}_{kind}.npz").is_file()]
        if missing:
            raise ParameterError(f"--data {a.data!r} lacks {', '.join(missing[:4])}"
                                 f"{f' (and {len(missing) - 4} more)' if len(missing) > 4 else ''} "
                                 f"(N3MR/SoftRas layout: CLASS_SPLIT_images.npz, CLASS_SPLIT_voxels.npz)")
    if Path(a.output).exists() and not Path(a.output).is_dir():
        raise ParameterError(f"-o {a.output!r} is a file; name the output directory")
    for option, value in (("--steps", a.steps), ("--batch-size", a.batch_size)):
        if value < 1:
            raise ParameterError(f"{option} must be >= 1, got {value}")
    for option, value in (("--tau", a.tau), ("--lr", a.lr)):
        if not (value > 0 and math.isfinite(value)):
            raise ParameterError(f"{option} must be a finite number > 0, got {value}")
    if a.render_size is not None and a.render_size < 1:
        raise ParameterError(f"--render-size must be >= 1, got {a.render_size}")
    if not 0 <= a.subdivisions <= 8:  # the template icosphere's domain (gendr.scenes.icosphere)
        raise ParameterError(f"--subdivisions must be in [0, 8], got {a.subdivisions}")
    if a.eval_views:
        try:
            views = [int(v) for v in a.eval_views.split(",")]
        except ValueError:
            raise ParameterError(f"--eval-views expects comma-separated view ids, got {a.eval_views!r}") from None
        if not all(0 <= v < NUM_VIEWS for v in views):
            raise ParameterError(f"--eval-views {a.eval_views!r}: view ids are 0 ... {NUM_VIEWS - 1}")
    torch_device(a.device)  # the torch backend's check (ParameterError / BackendUnavailableError)


def main_cli(a) -> int:
    check_cli(a)
    out = Path(a.output)
    out.mkdir(parents=True, exist_ok=True)
    if a.synthetic:
        data_dir = out / "data"
        classes = make_synthetic_dataset(data_dir, classes=classes_of(a), image_size=64)
    else:
        data_dir, classes = Path(a.data), classes_of(a)
    cfg = dict(distribution=a.distribution, tconorm=a.tconorm, instance=a.instance, tau=a.tau, lr=a.lr,
               batch_size=a.batch_size, steps=a.steps, subdivisions=a.subdivisions, render_size=a.render_size,
               device=a.device, backend=a.backend, seed=a.seed)
    train_data = ShapeNetViews(data_dir, classes, a.train_split)
    eval_data = ShapeNetViews(data_dir, classes, a.eval_split)
    model, hist = train(train_data, cfg, log=print)
    views = [int(v) for v in a.eval_views.split(",")] if a.eval_views else None
    metrics = evaluate(model, eval_data, views=views, voxel_order=a.voxel_order)
    metrics.update(instance=hist["instance"], train_seconds=hist["seconds"], final_loss=hist["loss"][-1],
                   first_loss=hist["loss"][0], config=cfg)
    torch.save(model.state_dict(), out / "model.pt")
    (out / "history.json").write_text(json.dumps(hist))
    (out / "metrics.json").write_text(json.dumps(metrics, indent=2))
    print(json.dumps({k: metrics[k] for k in ("class_iou", "mean_iou", "evaluated", "train_seconds")}, indent=2))
    return 0
