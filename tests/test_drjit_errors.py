"""The Dr.Jit backend raises the same typed errors, with the same messages, as the torch backend
(the input cases of test_render_errors.py, run through both), plus its own device errors."""
from __future__ import annotations

import math

import numpy as np
import pytest

dr = pytest.importorskip("drjit", reason="the Dr.Jit backend needs drjit (pip install gendr[drjit])")
torch = pytest.importorskip("torch")

import gendr  # noqa: E402
from gendr.errors import BackendUnavailableError, GendrError, ParameterError  # noqa: E402

V = torch.tensor([[-0.5, -0.5, 0.0], [0.5, -0.5, 0.0], [0.0, 0.5, 0.0], [0.3, 0.3, 0.1]], dtype=torch.float64)
F = torch.tensor([[0, 1, 2], [1, 3, 2]])
CAM = gendr.PerspectiveCamera()


def _faces_with(bad):
    f = F.clone()
    f[1, 1] = bad
    return f


def _nonfinite(value):
    v = V.clone()[None].repeat(2, 1, 1)
    v[1, 3, 2] = value
    return v


def _nan_colour():
    c = torch.rand(4, 3, dtype=torch.float64)
    c[2, 1] = math.nan
    return c


#: name -> (vertices, faces, camera, render kwargs)
CASES = {
    **{f"vertices_shape_{s}": (lambda s=s: torch.zeros(s, dtype=torch.float64), F, CAM, {})
       for s in [(4, 2), (1, 4, 3, 1), (4,), (4, 4), (2, 0, 3)]},
    **{f"vertices_dtype_{d}": (lambda d=d: V.to(d), F, CAM, {})
       for d in [torch.int64, torch.int32, torch.float16, torch.bfloat16, torch.bool, torch.complex64]},
    **{f"numpy_vertices_dtype_{np.dtype(d).name}": (lambda d=d: V.numpy().astype(d), F, CAM, {})
       for d in [np.int64, np.int32, np.float16, np.bool_]},
    "vertices_object_array": (lambda: np.array([["a", "b", "c"]] * 4), F, CAM, {}),
    **{f"faces_dtype_{i}": (lambda: V, f, CAM, {})
       for i, f in enumerate([F.double(), F.float(), F.bool(), F.numpy().astype(np.float32)])},
    **{f"faces_shape_{i}": (lambda: V, f, CAM, {})
       for i, f in enumerate([torch.tensor([0, 1, 2]), torch.tensor([[0, 1, 2, 3]]), torch.zeros(1, 3, 1, dtype=torch.long)])},
    **{f"face_index_{b}": (lambda: V, _faces_with(b), CAM, {}) for b in (4, -1, 17)},
    **{f"nonfinite_vertex_{x}": (lambda x=x: _nonfinite(x), F, CAM, {}) for x in (math.nan, math.inf, -math.inf)},
    "colours_shape_0": (lambda: V, F, CAM, {"vertex_colors": torch.rand(3, 3, dtype=torch.float64)}),
    "colours_shape_1": (lambda: V, F, CAM, {"vertex_colors": torch.rand(4, 4, dtype=torch.float64)}),
    "colours_shape_2": (lambda: V, F, CAM, {"vertex_colors": torch.rand(1, 1, 4, 3, dtype=torch.float64)}),
    "colours_shape_3": (lambda: V, F, CAM, {"face_colors": torch.rand(4, 3, dtype=torch.float64)}),
    "colours_shape_4": (lambda: V, F, CAM, {"face_colors": torch.rand(2, 2, dtype=torch.float64)}),
    "colour_nonfinite": (lambda: V, F, CAM, {"vertex_colors": _nan_colour()}),
    "both_colour_kinds": (lambda: V, F, CAM, {"vertex_colors": torch.rand(4, 3, dtype=torch.float64),
                                               "face_colors": torch.rand(2, 3, dtype=torch.float64)}),
    "not_a_camera": (lambda: V, F, "perspective", {}),
    "camera_batch_mismatch": (lambda: V[None].repeat(2, 1, 1), F,
                              gendr.orbit_camera(torch.tensor([0.0, 10.0, 20.0], dtype=torch.float64), 0.0, 3.0), {}),
    "camera_batches_differ": (lambda: V, F, gendr.PerspectiveCamera(
        eye=torch.tensor([[0.0, 0.0, 3.0]] * 2, dtype=torch.float64),
        fov_y=torch.tensor([30.0, 40.0, 50.0], dtype=torch.float64)), {}),
    "camera_parameter_shape": (lambda: V, F, gendr.PerspectiveCamera(eye=torch.zeros(2, 2, dtype=torch.float64)), {}),
    "camera_parameter_nan": (lambda: V, F, gendr.PerspectiveCamera(
        eye=torch.tensor([0.0, math.nan, 3.0], dtype=torch.float64)), {}),
    # (a NaN in a NumPy camera parameter is caught when the camera is made: tests/test_camera_checks.py)
}


def _raise(backend, case):
    make_v, faces, cam, kw = CASES[case]
    r = gendr.Renderer(image_size=(8, 10), backend=backend)
    with pytest.raises(GendrError) as e:
        r.render(make_v(), faces, cam, **kw)
    return e.value


@pytest.mark.parametrize("case", list(CASES))
def test_same_error_as_torch(case):
    ref, got = _raise("torch", case), _raise("drjit", case)
    assert type(got) is type(ref)
    # (NumPy faces: the torch backend converts them first and spells the dtype "torch.float32")
    assert str(got) in (str(ref), str(ref).replace("torch.float32", "float32"))


def test_drjit_input_dtype_errors():
    from drjit.llvm.ad import TensorXi, TensorXf
    r = gendr.Renderer(image_size=(8, 10), backend="drjit")
    with pytest.raises(gendr.DTypeError, match="vertices"):
        r.render(TensorXi(np.zeros((4, 3), np.int32)), F, CAM)
    with pytest.raises(gendr.DTypeError, match="faces"):
        r.render(TensorXf(V.numpy().astype(np.float32)), TensorXf(F.numpy().astype(np.float32)), CAM)


def test_device_selection():
    """device=None follows the inputs (Dr.Jit tensors: their backend; torch tensors: LLVM on the CPU,
    CUDA on a GPU; NumPy: CUDA when available); an explicit device is used for every render."""
    from drjit.llvm.ad import TensorXf64
    cuda = dr.has_backend(dr.JitBackend.CUDA)
    r = gendr.Renderer(backend="drjit", image_size=(8, 10))
    assert r.backend.device is None
    img = r.render(V, F, CAM)  # torch on the CPU -> LLVM, the image a CPU tensor
    assert isinstance(img, torch.Tensor) and img.device.type == "cpu"
    assert dr.backend_v(r.render(TensorXf64(V.numpy()), F.numpy(), CAM)) == dr.JitBackend.LLVM
    assert dr.backend_v(r.render(V.numpy(), F.numpy(), CAM)) == (dr.JitBackend.CUDA if cuda else dr.JitBackend.LLVM)
    assert gendr.Renderer(backend="drjit", device="llvm").backend.device == "llvm"
    with pytest.raises(ParameterError, match="device"):
        gendr.Renderer(backend="drjit", device="tpu")
    if not cuda:
        with pytest.raises(BackendUnavailableError, match="cuda"):
            gendr.Renderer(backend="drjit", device="cuda")
        return
    from drjit.cuda.ad import TensorXf64 as CudaTensor
    on_gpu = gendr.Renderer(backend="drjit", device="cuda", image_size=(8, 10))
    v = V.clone().requires_grad_(True)
    img = on_gpu.render(v, F, CAM)  # computed on CUDA, back on the vertices' device, differentiably
    assert img.device.type == "cpu"
    img.sum().backward()
    assert v.grad.device.type == "cpu" and float(v.grad.abs().sum()) > 0
    with pytest.raises(ParameterError, match="vertices is a Dr.Jit LLVM array"):
        on_gpu.render(TensorXf64(V.numpy()), F.numpy(), CAM)
    # NumPy vertices: the first input with a device decides (a CPU torch τ: LLVM, the image on the CPU)
    tau_cpu = torch.tensor(0.05, dtype=torch.float64, requires_grad=True)
    img = gendr.Renderer(backend="drjit", image_size=(8, 10), tau=tau_cpu).render(V.numpy(), F.numpy(), CAM)
    assert img.device.type == "cpu"
    with pytest.raises(ParameterError, match="camera parameter eye"):
        r.render(CudaTensor(V.numpy()), F.numpy(), gendr.PerspectiveCamera(eye=TensorXf64(np.array([0.0, 0.0, 3.0]))))


@pytest.mark.parametrize("blend", [None, "softmax", "hard"])
def test_no_faces_gives_the_background(blend):
    """F = 0 is valid input: both backends render alpha 0 and the background."""
    f = torch.zeros(0, 3, dtype=torch.long)
    imgs = [gendr.Renderer(backend=be, image_size=(8, 10), blend=blend, background=(0.1, 0.2, 0.3)).render(
        V.clone().requires_grad_(True), f, CAM).detach() for be in ("torch", "drjit")]
    assert imgs[0].shape == imgs[1].shape == (1, 8, 10, 4)
    assert float((imgs[0] - imgs[1]).abs().max()) == 0.0
    assert float(imgs[0][..., 3].abs().max()) == 0.0  # no coverage
    if blend is not None:  # (without a blend the RGB channels are 0: alpha only)
        assert torch.equal(imgs[0][..., :3], torch.tensor([0.1, 0.2, 0.3], dtype=imgs[0].dtype).expand(1, 8, 10, 3))


@pytest.mark.parametrize("case", ["no faces", "heaviside or"])
def test_an_image_no_gradient_reaches_is_still_differentiable(case):
    """As with the torch backend, ``loss.backward()`` works when no gradient reaches the inputs (an
    empty mesh; heaviside with "or" and no RGB): the vertices get a zero gradient (both backends: code
    that reads ``v.grad`` works after a backend switch) instead of an error."""
    f = torch.zeros(0, 3, dtype=torch.long) if case == "no faces" else F
    kw = dict(distribution="heaviside", tconorm="or", blend=None) if case == "heaviside or" else {}
    for be in ("torch", "drjit"):
        v = V.clone().requires_grad_(True)
        img = gendr.Renderer(backend=be, image_size=8, **kw).render(v, f, CAM)
        assert img.requires_grad, be
        img.sum().backward()
        assert v.grad is not None and v.grad.shape == v.shape and v.grad.dtype == v.dtype, be
        assert float(v.grad.abs().max()) == 0.0, be
