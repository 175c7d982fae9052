#!/usr/bin/env bash
# The whole-grid study of docs/experiments.md ("The whole grid"), resumable: run it again to go on
# where it stopped (rows are keyed by config; rows of other code are kept, each records its code).
#
#   bash experiments/paper_grid.sh shape    # 1,242 instances, shape optimisation, reduced paper protocol
#   bash experiments/paper_grid.sh pose     # 23 distributions x 5 T-conorms, pose, 3 bins x 17 pairs
#
# Needs the paper's meshes in $GENDR_PAPER_DATA (default ~/.cache/gendr/paper_data; see
# docs/experiments.md). WORKERS (default 2) local processes, one thread each; SCHEDULER=tcp://host:8786
# runs on a Dask cluster instead; RESULTS (default experiments/results) is where the rows go.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
GENDR="${GENDR:-.venv/bin/gendr}"   # a command (may have words: "python -m gendr.cli")
RESULTS="${RESULTS:-experiments/results}"
WORKERS="${WORKERS:-2}"
RUN=(--workers "$WORKERS" --other-code keep -q)
[[ -n "${SCHEDULER:-}" ]] && RUN=(--scheduler "$SCHEDULER" --other-code keep -q)
FIVE="max,probabilistic,einstein,yager(2),dombi(0.5)"

case "${1:-}" in
shape)
    # reduced protocol: elevation 30 only, lr 10^-1.5 only, widths 1e-1, 1e-2, 1e-3, then best * 10^(+-0.5)
    COMMON=(--experiment shape --protocol paper --taus 0.1,0.01,0.001 --fine-steps=-0.5,0.5 --seeds 0
            -o "$RESULTS/paper_shape_grid.jsonl")
    # the five T-conorms of the pose sweep first (every distribution, plain and squared), then the rest
    $GENDR experiment sweep "${COMMON[@]}" --dists all --tconorms "$FIVE" "${RUN[@]}"
    # SoftRas' "average" (not a T-conorm, outside the 1,242) beside them, as the paper's heatmaps have it
    $GENDR experiment sweep "${COMMON[@]}" --dists all --tconorms average "${RUN[@]}"
    $GENDR experiment sweep "${COMMON[@]}" --instances all "${RUN[@]}"
    ;;
pose)
    $GENDR experiment sweep --experiment pose --protocol paper --dists all --variants plain --tconorms "$FIVE" \
        --bins 15-35,35-55,55-75 --set pairs=17 --seeds 0 --no-refine \
        -o "$RESULTS/paper_pose_grid.jsonl" "${RUN[@]}"
    ;;
*)
    sed -n '2,12p' "${BASH_SOURCE[0]}" | sed 's/^# \{0,1\}//'; exit 2 ;;
esac
