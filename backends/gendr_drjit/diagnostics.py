"""Kernel statistics of a call, from Dr.Jit's kernel history (used by the benchmark and the tests
that check that changing τ, vertices or camera values compiles no new kernel)."""
from __future__ import annotations

import drjit as dr


def kernel_stats(fn) -> dict:
    """Run ``fn()`` once; return kernels launched, kernels compiled (cache misses) and the summed
    kernel execution time in ms."""
    dr.kernel_history_clear()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        fn()
        hist = dr.kernel_history()
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    jit = [k for k in hist if k.get("type") == dr.KernelType.JIT]
    return {"kernels_launched": len(jit), "kernels_compiled": sum(1 for k in jit if not k.get("cache_hit")),
            "kernel_exec_ms": sum(k.get("execution_time", 0.0) for k in hist)}
