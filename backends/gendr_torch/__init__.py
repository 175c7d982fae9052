"""gendr's PyTorch backend (entry point ``gendr.backends: torch``).

Device-agnostic: it renders on the device of the vertices (CPU or CUDA). float32 and float64.
"""
from .backend import TorchBackend

__all__ = ["TorchBackend"]
