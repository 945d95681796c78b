#!/usr/bin/env bash
# svgir's checks on a machine with a real GPU, in one summary (issue: GPU stage 1).
#
#   bash tools/gpu_check.sh prepare   # here: build, strip the binaries into .gpubin/, copy a
#                                     # lego_400 subset into .gpudata/ (both git-ignored)
#   bash tools/gpu_check.sh           # there, from the repository root, with .gpubin, .gpudata
#                                     # (and .gl, the Vulkan loader) carried: no build there
#
# The run: the GPU kernel tests (svgir-gpu's raster, stage-1, trace, shade and stage-2 tests on the
# adapter), the raster line (400 x 400, 100k Gaussians, forward and forward + backward), the trace
# line (K = 64 and K = 384 micro-buffers of 100k surfels), the shade line (K = 64 and 384 beside
# the CPU), lego_400's 30k-iteration
# stage 1 on the GPU against its 35 dB target, and one stage-1 iteration timing of the GPU beside
# the machine's CPU path on the shipped scene. Each step is time-boxed so the whole stays under
# 8 minutes; the summary goes to stdout and $OUT/gpu_check.txt when OUT is set.
# Knobs: SVGIR_GPU_ADAPTER (default NVIDIA), GPU_CHECK_LEGO_ITERS (30000), GPU_CHECK_QUICK=1 (a
# smoke test of the script itself, e.g. on lavapipe: small sizes and runs).
set -uo pipefail
cd "$(dirname "$0")/.."
BIN=.gpubin
DATA=.gpudata

if [ "${1:-}" = prepare ]; then
  set -e
  mkdir -p "$BIN" "$DATA"
  grep -qx '/.gpubin/' .git/info/exclude 2>/dev/null || echo '/.gpubin/' >>.git/info/exclude
  grep -qx '/.gpudata/' .git/info/exclude 2>/dev/null || echo '/.gpudata/' >>.git/info/exclude
  cargo build --release -p svgir-cli
  strip -o "$BIN/svgir" target/release/svgir
  for t in raster features stage1 trace shade gather consistency stage2; do
    exe=$(cargo test --release -p svgir-gpu --test "$t" --no-run --message-format=json 2>/dev/null |
      python3 -c 'import json,sys
for l in sys.stdin:
    m=json.loads(l)
    if m.get("executable") and m.get("target",{}).get("kind")==["test"]: print(m["executable"])' | tail -1)
    strip -o "$BIN/test-$t" "$exe"
  done
  lego=../shared/data/nerf_synthetic/lego_400
  if [ -d "$lego" ]; then
    rm -rf "$DATA/lego_400" && mkdir -p "$DATA/lego_400/test"
    cp -r "$lego/train" "$lego/transforms_train.json" "$DATA/lego_400/"
    # 50 of the 200 test views (the transfer limit), evenly spaced, their photos only.
    python3 - "$lego" "$DATA/lego_400" <<'PY'
import json, shutil, sys
src, dst = sys.argv[1], sys.argv[2]
t = json.load(open(f"{src}/transforms_test.json"))
t["frames"] = t["frames"][::4]
for f in t["frames"]:
    shutil.copy(f"{src}/{f['file_path'].lstrip('./')}.png", f"{dst}/{f['file_path'].lstrip('./')}.png")
json.dump(t, open(f"{dst}/transforms_test.json", "w"), indent=1)
PY
  fi
  du -sh "$BIN" "$DATA"
  exit 0
fi

# The Vulkan loader, carried as .debs (../.library/device/README.md), and NVIDIA's ICD.
if [ -d .gl ] && ! ldconfig -p | grep -q libvulkan; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done
  ldconfig
fi
[ -e /usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json ] &&
  export VK_DRIVER_FILES="${VK_DRIVER_FILES:-/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json}"
export SVGIR_GPU_ADAPTER="${SVGIR_GPU_ADAPTER:-NVIDIA}" SVGIR_REQUIRE_GPU=1
export XDG_RUNTIME_DIR="${XDG_RUNTIME_DIR:-/tmp/svgir-xdg}"
mkdir -p "$XDG_RUNTIME_DIR" && chmod 700 "$XDG_RUNTIME_DIR"
# The tests find the shipped scene where they were built (CARGO_MANIFEST_DIR): point that path here.
built=$(grep -a -o '/[[:alnum:]/._+-]*/crates/svgir-gpu/../../scenes/bowl_fruit_128' "$BIN/test-stage1" | head -1)
root=${built%/crates/svgir-gpu/../../scenes/bowl_fruit_128}
if [ -n "$root" ] && [ ! -e "$root/scenes" ]; then mkdir -p "$(dirname "$root")" && ln -sfn "$PWD" "$root"; fi

quick=${GPU_CHECK_QUICK:-0}
iters=${GPU_CHECK_LEGO_ITERS:-30000}
size=400 n=100000 reps=20 side=500
[ "$quick" = 1 ] && { iters=60; size=128; n=5000; reps=2; side=20; }
log=$(mktemp -d)
summary=()
step() { # name, seconds, command...
  local name=$1 secs=$2; shift 2
  local t0=$SECONDS
  timeout "$secs" "$@" >"$log/$name.txt" 2>&1
  local rc=$?
  summary+=("$(printf '%-8s rc %-3s %4ss' "$name" "$rc" $((SECONDS - t0)))")
  return $rc
}
"$BIN/svgir" --version >/dev/null 2>&1 || { echo "no $BIN/svgir: run 'bash tools/gpu_check.sh prepare' first" >&2; exit 2; }
step tests 180 sh -c "$BIN/test-raster && $BIN/test-features && $BIN/test-stage1 && $BIN/test-trace && $BIN/test-shade && $BIN/test-gather && $BIN/test-consistency && $BIN/test-stage2"
step raster 60 "$BIN/svgir" bench raster --device gpu --size "$size" --gaussians "$n" --reps "$reps"
step trace 60 "$BIN/svgir" bench trace --device gpu --gaussians "$n" --reps 3
step shade 60 "$BIN/svgir" bench pbr --device gpu --gaussians "$n" --reps 3
if [ -d "$DATA/lego_400" ]; then
  step lego 240 "$BIN/svgir" train "$DATA/lego_400" --out "$log/lego" --profile views --iterations "$iters" \
    --densify-grad 1.5e-4 --device gpu
else
  summary+=("lego     not run: no $DATA/lego_400 (prepare copies it from ../shared/data)")
fi
step side 120 "$BIN/svgir" bench train --device cpu,gpu --scene scenes/bowl_fruit_128 --train-iterations "$side" \
  --train-eval-every "$side" --train-out "$log/side"

{
  echo "svgir gpu_check $(date -u +%F) commit $(git rev-parse --short HEAD 2>/dev/null || echo '?')"
  grep -h -m1 "device: GPU" "$log"/*.txt 2>/dev/null | head -1
  printf '%s\n' "${summary[@]}"
  echo "--- tests"; grep -h "test result\|panicked\|FAILED" "$log/tests.txt" | head -8
  echo "--- raster (target at 400 x 400 / 100k: forward+backward <= 1 ms)"; grep "^|" "$log/raster.txt"
  echo "--- trace (target: K = 64 micro-buffers of 100k surfels <= 0.2 s)"; grep "^|" "$log/trace.txt"
  echo "--- shade (GPU beside the CPU, upload and read-back included)"; grep -A6 "shade bench" "$log/shade.txt" | grep "^|"
  if [ -f "$log/lego/eval.json" ]; then
    echo "--- lego_400 ($iters iterations; target >= 35 dB in <= 3 min)"
    python3 -c "import json; e=json.load(open('$log/lego/eval.json')); t=json.load(open('$log/lego/timings.json')); print('test PSNR %.2f dB on %d views, %.2f ms per iteration, %.1f min of steps' % (e['psnr'], e['views'], t['ms_per_iteration']['gpu_step'], t['ms_per_iteration']['gpu_step'] * t['iterations'] / 6e4))"
  elif [ -f "$log/lego.txt" ]; then
    echo "--- lego_400"; tail -3 "$log/lego.txt"
  fi
  echo "--- stage 1 side by side (target: GPU >= 10x the CPU per iteration)"; grep "^|" "$log/side.txt"
  for r in "$log"/side/*/timings.json; do [ -f "$r" ] && echo "$(basename "$(dirname "$r")"): $(tr -d '\n ' <"$r")"; done
} | tee "$log/summary.txt"
[ -n "${OUT:-}" ] && cp "$log/summary.txt" "$OUT/gpu_check.txt" && cp "$log/tests.txt" "$OUT/tests.txt"
true
