"""gendr_experiments — the experiments of the GenDR paper (Petersen et al., CVPR 2022, §5) on gendr.

* :mod:`.shape`  — shape optimisation from 24 silhouettes (§5.1): :func:`run_shape`
* :mod:`.pose`   — camera-pose optimisation with a decaying τ (§5.2): :func:`run_pose`
* :mod:`.sweep`  — resumable sweeps over the paper's grid × τ × learning rates × seeds, on a local
  process pool or a Dask cluster, with the paper's coarse-then-fine best-setting search
* :mod:`.figures` — heatmaps laid out like the paper's figures, top-10 % histograms, GIFs
* :mod:`.recon`  — single-view 3D reconstruction (§5.3) on the N3MR/SoftRas data layout
* :mod:`.cli`    — ``gendr experiment shape|pose|sweep|figures|recon`` (see docs/experiments.md)
"""
__version__ = "0.1.0"

from .shape import SHAPE_DEFAULTS, run_shape
from .pose import POSE_DEFAULTS, run_pose
from .sweep import ResultStore, best_setting_search, execute, expand, load_rows, run_config, summarize_best

__all__ = ["SHAPE_DEFAULTS", "run_shape", "POSE_DEFAULTS", "run_pose", "ResultStore", "best_setting_search",
           "execute", "expand", "load_rows", "run_config", "summarize_best"]
