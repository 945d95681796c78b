#!/usr/bin/env bash
# Both stages on every Blender-Cycles scene in ../shared/data/synthetic, then the SPEC 8 table.
#
#   bash tools/synthetic_table.sh [OUT] [STAGE2_ITERATIONS] [-- `svgir inverse` options]
#        (defaults: runs/synthetic, 1500, and the table's stage-2 options below)
#
# Stage 1: STAGE1_ITERATIONS (env, default SPEC's 30000) from 20k random points, black background,
#          densify every 100 until half way, opacity reset every 3000.
# Stage 2: STAGE2_ITERATIONS (SPEC's schedule is 20000), relighting evaluated at K = 384, with
#          `svgir inverse`'s measured profile (Stage2Config::for_profile, the one place its
#          settings are resolved). Options after `--` are passed on (e.g. `-- --profile spec`).
# Environment: SCENES="cup_and_ball suzanne_marble" restricts the scenes; STAGE1_OPTIONS="..." adds
# `svgir train` options (e.g. "--weight opacity_binary=0.05"); SVGIR=path runs that binary instead of
# building one (an experiment that must not pick up a build in progress).
#
# Re-running with the same OUT continues: an interrupted stage resumes from its last checkpoint
# and finished scenes are only re-tabulated. Use a new OUT for new settings.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
DATA="$ROOT/../shared/data/synthetic"
OUT="${1:-runs/synthetic}"
ITERS2="${2:-1500}"
shift $(( $# < 2 ? $# : 2 ))
[ "${1:-}" = "--" ] && shift
[ $# -gt 0 ] || set -- --profile measured
ITERS1="${STAGE1_ITERATIONS:-30000}"
[ -d "$DATA" ] || { echo "error: $DATA not found (the shared data folder next to the checkout)" >&2; exit 1; }
if [ -z "${SVGIR:-}" ]; then
  cargo build --release --manifest-path "$ROOT/Cargo.toml" -p svgir-cli
  SVGIR="$ROOT/target/release/svgir"
fi
read -r -a stage1_options <<< "${STAGE1_OPTIONS:-}"
for scene in ${SCENES:-$(ls "$DATA")}; do
  run="$OUT/$scene"
  if [ ! -f "$run/point_cloud.ply" ]; then
    resume=()
    [ -f "$run/checkpoint.bin" ] && resume=(--resume)
    "$SVGIR" train "$DATA/$scene" --out "$run" --iterations "$ITERS1" --background black --init-points 20000 \
      --densify-every 100 --densify-until $((ITERS1 / 2)) --opacity-reset-every 3000 \
      "${stage1_options[@]}" "${resume[@]}"
  fi
  if [ ! -f "$run/stage2/eval.json" ]; then
    resume=()
    [ -f "$run/stage2/checkpoint.bin" ] && resume=(--resume)
    "$SVGIR" inverse --run "$run" --iterations "$ITERS2" --turntable 0 "$@" "${resume[@]}"
  fi
done
# The table: `svgir eval` prints each run's SPEC 8 evaluation (saved by `svgir inverse`) and the
# markdown table of all scenes (`svgir eval --run RUN/stage2` evaluates a run again).
"$SVGIR" eval --cached --run "$OUT"/*/stage2
