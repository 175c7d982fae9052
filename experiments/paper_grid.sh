#!/usr/bin/env bash
# The whole-grid study of docs/experiments.md ("The whole grid"), resumable: run it again to go on
# where it stopped (rows are keyed by config; rows of other code are kept, each records its code).
#
#   bash experiments/paper_grid.sh shape    # 1,242 instances, shape optimisation, reduced paper protocol
#   bash experiments/paper_grid.sh pose     # 23 distributions x 5 T-conorms, pose, 3 bins x 17 pairs
#   SCHEDULER=tcp://host:8786 bash experiments/paper_grid.sh shape-full   # the paper's full protocols,
#   SCHEDULER=tcp://host:8786 bash experiments/paper_grid.sh pose-full    # for a cluster ("Scale" in the docs)
#
# Needs the paper's meshes in $GENDR_PAPER_DATA (default ~/.cache/gendr/paper_data; see
# docs/experiments.md). WORKERS (default 2) local processes, one thread each; SCHEDULER=tcp://host:8786
# runs on a Dask cluster instead; RESULTS (default experiments/results) is where the rows go;
# DEVICE=cuda renders on a GPU (sweep --device; rows keep their keys and record the device).
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
GENDR="${GENDR:-.venv/bin/gendr}"   # a command (may have words: "python -m gendr.cli")
RESULTS="${RESULTS:-experiments/results}"
WORKERS="${WORKERS:-2}"
DEVICE="${DEVICE:-cpu}"
RUN=(--workers "$WORKERS" --other-code keep --retry-errors --device "$DEVICE" -q)
[[ -n "${SCHEDULER:-}" ]] && RUN=(--scheduler "$SCHEDULER" --other-code keep --retry-errors --device "$DEVICE" -q)
# a sweep exits 1 when some of its runs ended in an error (their rows say why; --retry-errors reruns
# them on the next pass): report it and go on with the rest of the grid
sweep() { $GENDR experiment sweep "$@" || echo "paper_grid.sh: a sweep ended with errors (see its rows); going on" >&2; }
FIVE="max,probabilistic,einstein,yager(2),dombi(0.5)"
LIGHT="uniform,cubic_hermite,wigner_semicircle,gaussian,laplace,logistic,hyperbolic_secant,gumbel_max,gumbel_min"
LIGHT+=",exponential,exponential rev,gamma(0.5),gamma(0.5) rev,gamma(2),gamma(2) rev,gamma(3),gamma(3) rev"
LIGHT+=",gamma(5),gamma(5) rev,levy"

case "${1:-}" in
shape)
    # reduced protocol: elevation 30 only, lr 10^-1.5 only, widths 0.003, 0.01, 0.03 (~10^-2.5, -2, -1.5), then
    # best * 10^(+-0.25). (A first pass with widths 0.1, 0.01, 0.001 found the best at 0.01 for 33 of
    # 42 instances and at 0.1 only for poor ones, where a run costs 10-30x more: gendr experiment cost.)
    COMMON=(--experiment shape --protocol paper --taus 0.003,0.01,0.03 --fine-steps=-0.25,0.25 --seeds 0
            -o "$RESULTS/paper_shape_grid.jsonl")
    # the five T-conorms of the pose sweep first (every distribution, plain and squared), then the rest
    sweep "${COMMON[@]}" --dists all --tconorms "$FIVE" "${RUN[@]}"
    # SoftRas' "average" (not a T-conorm, outside the 1,242) beside them, as the paper's heatmaps have it;
    # then the T-conorms the paper calls poor (Y4, A2, A4, D2, D4, SS-2, SS-4), so that finding is
    # testable early, then every other T-conorm. All of it on the 20 light-tailed distributions first:
    # a heavy-tailed instance (cauchy, reciprocal, levy rev; plain) costs as much as ~30 light ones
    # (gendr experiment cost), so the T-conorm columns fill on most rows before the costly ones run
    POOR="yager(4),aczel_alsina(2),aczel_alsina(4),dombi(2),dombi(4),schweizer_sklar(-2),schweizer_sklar(-4)"
    for DISTS in "$LIGHT" all; do
        for TCN in average "$POOR" all; do
            sweep "${COMMON[@]}" --dists "$DISTS" --tconorms "$TCN" "${RUN[@]}"
        done
    done
    ;;
pose)
    sweep --experiment pose --protocol paper --dists all --variants plain --tconorms "$FIVE" \
        --bins 15-35,35-55,55-75 --set pairs=17 --seeds 0 --no-refine \
        -o "$RESULTS/paper_pose_grid.jsonl" "${RUN[@]}"
    ;;
shape-full)
    # §5.1 on every instance: 5 elevations x 3 lr x 7 tau, then 21 tau at 0.1-decade steps around each
    # instance's best (18 new, 19 around a best at the grid's edge: the others are coarse tau): 242,215 runs,
    # ~4,000 CPU-hours (gendr experiment cost). gendr's tau is
    # a width (squared instances render with width^2): the squared half searches widths 10^-0.5 ...
    # 10^-3.5 in 0.05-decade steps, i.e. the paper's renderer tau 1e-1 ... 1e-7 in 0.1-decade steps.
    FULL=(--experiment shape --protocol paper --dists all --tconorms all
          --lrs 0.05623413251903491,0.03162277660168379,0.01778279410038923 --elevations=-60,-30,0,30,60
          --seeds 0 -o "$RESULTS/paper_shape_full.jsonl")
    sweep "${FULL[@]}" --variants plain --taus 0.1,0.01,0.001,0.0001,1e-05,1e-06,1e-07 \
        --fine-steps=-1.0,-0.9,-0.8,-0.7,-0.6,-0.5,-0.4,-0.3,-0.2,-0.1,0.0,0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8,0.9,1.0 \
        "${RUN[@]}"
    sweep "${FULL[@]}" --variants squared \
        --taus 0.31622776601683794,0.1,0.03162277660168379,0.01,0.0031622776601683794,0.001,0.00031622776601683794 \
        --fine-steps=-0.5,-0.45,-0.4,-0.35,-0.3,-0.25,-0.2,-0.15,-0.1,-0.05,0.0,0.05,0.1,0.15,0.2,0.25,0.3,0.35,0.4,0.45,0.5 \
        "${RUN[@]}"
    ;;
pose-full)
    # §5.2 on every instance: 3 bins x 200 pairs (one run each) x lr 0.1, 0.3, 1,000 steps: 7,452 runs,
    # ~14,000 CPU-hours; PAIRS=20 SEEDS=0-9 cuts the longest run (~17 h) tenfold with other pair draws
    sweep --experiment pose --protocol paper --instances all --lrs 0.1,0.3 \
        --bins 15-35,35-55,55-75 --set pairs="${PAIRS:-200}" --seeds "${SEEDS:-0}" --no-refine \
        -o "$RESULTS/paper_pose_full.jsonl" "${RUN[@]}"
    ;;
*)
    sed -n '2,13p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 2 ;;
esac
