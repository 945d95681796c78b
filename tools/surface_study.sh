#!/usr/bin/env bash
# How opaque and thin stage 1's surfaces are under one change at a time (docs/experiments.md,
# "Opaque, thin surfels"). For each variant: stage 1 on SCENE, then
#   - svgir-diagnose surface_layers: carriers of 90% of the weight and their opacity, the weight
#     from surfels of opacity >= 0.8, surfels and depth layers per covered pixel (test views);
#   - the held-out PSNR and normal MAE of stage 1 (eval.json);
#   - Chamfer to the true mesh as % of its bounding-box diagonal (svgir export --reference);
#   - the fitted-oracle albedo: the true albedo fitted through the rasterizer to the training views
#     (svgir inverse --iterations 0 --gt-materials; relighting cut to K = 64, 4 lights, as only the
#     albedo is read).
# Prints one markdown row per variant. Usage:
#   bash tools/surface_study.sh OUT [SCENE] [ITERATIONS]     (SCENE default scenes/bowl_fruit_128)
# The variants are the VARIANTS array below: "name|extra svgir train arguments".
set -euo pipefail
OUT=${1:?usage: surface_study.sh OUT [SCENE] [ITERATIONS]}
SCENE=${2:-scenes/bowl_fruit_128}
ITERS=${3:-5000}
SVGIR=${SVGIR:-target/release/svgir}
LAYERS=${LAYERS:-target/release/surface_layers}
VARIANTS=(
  "default|"
  "opacity_binary 0.01|--weight opacity_binary=0.01"
  "opacity_binary 0.05|--weight opacity_binary=0.05"
  "distortion 100|--weight distortion=100"
  "normal 0.05 flat (2DGS)|--weight normal_start=0.05 --weight normal_ramp=0"
  "no Gaussian budget|--max-gaussians 0"
  "2DGS: no budget, distortion 1000, normal 0.05|--max-gaussians 0 --weight distortion=1000 --weight normal_start=0.05 --weight normal_ramp=0"
  "no budget, opacity_binary 0.01|--max-gaussians 0 --weight opacity_binary=0.01"
  "no budget, opacity_binary 0.05|--max-gaussians 0 --weight opacity_binary=0.05"
)
[ -x "$SVGIR" ] && [ -x "$LAYERS" ] || { echo "build first: cargo build --release -p svgir-cli -p svgir-diagnose" >&2; exit 1; }
mkdir -p "$OUT"
echo "| variant | Gaussians | carriers of 90%: mean / median opacity | weight from opacity >= 0.8 | surfels / depth layers per pixel | test PSNR | normal MAE | Chamfer % | fitted-oracle albedo |"
echo "|---|---|---|---|---|---|---|---|---|"
for v in "${VARIANTS[@]}"; do
  name=${v%%|*}; extra=${v#*|}
  run="$OUT/$(echo "$name" | tr -c 'A-Za-z0-9._-' '_')"
  # shellcheck disable=SC2086
  [ -f "$run/point_cloud.ply" ] || "$SVGIR" train "$SCENE" --iterations "$ITERS" $extra --out "$run" > "$run.train.log" 2>&1
  lay=$("$LAYERS" "$run/point_cloud.ply" "$SCENE" --stride 2)
  [ -f "$run/chamfer.json" ] || "$SVGIR" export --run "$run" --mesh-ply "$run/surface.ply" \
      --reference "$SCENE/mesh.ply" --report-json "$run/chamfer.json" > "$run.export.log" 2>&1
  [ -f "$run/stage2/eval.json" ] || "$SVGIR" inverse --run "$run" --iterations 0 --gt-materials \
      --relight-directions 64 --relight-lights 4 > "$run.oracle.log" 2>&1
  python3 - "$name" "$run" "$lay" <<'EOF'
import json, re, sys
name, run, lay = sys.argv[1], sys.argv[2], sys.argv[3]
n = re.search(r"(\d+) Gaussians", lay).group(1)
c = re.search(r"carriers of 90% of the weight: \d+ \(([\d.]+)%\), opacity mean ([\d.]+), median ([\d.]+)", lay)
o = re.search(r"opacity >= 0.8: ([\d.]+)%", lay).group(1)
l = re.search(r"weight > 0.1: ([\d.]+) .*depth layers: ([\d.]+)", lay)
e = json.load(open(f"{run}/eval.json"))
ch = json.load(open(f"{run}/chamfer.json"))["chamfer"]["chamfer_percent_of_diagonal"]
alb = json.load(open(f"{run}/stage2/eval.json"))["albedo"]["psnr"]
print(f"| {name} | {n} | {c.group(2)} / {c.group(3)} ({c.group(1)}% of surfels) | {o}% | {l.group(1)} / {l.group(2)} "
      f"| {e['psnr']:.2f} | {e['normal_mae_deg']:.2f} | {ch:.3f} | {alb:.2f} |")
EOF
done
