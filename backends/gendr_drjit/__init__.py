"""gendr's Dr.Jit backend (entry point ``gendr.backends: drjit``).

``gendr.Renderer(..., backend="drjit")``; renders on the inputs' device (LLVM for CPU arrays, CUDA
for GPU ones; ``device="llvm"|"cuda"`` overrides). float32 and float64 (the vertices' dtype). Inputs: Dr.Jit tensors, NumPy arrays or
torch tensors (torch in -> torch out, gradients flow back into torch).
"""
from .backend import DrJitBackend

__all__ = ["DrJitBackend"]
