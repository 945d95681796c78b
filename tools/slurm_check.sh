#!/usr/bin/env bash
# Runs the Slurm recipe (tools/slurm/capture_array.sbatch, docs/slurm.md) on a single-node Slurm
# started here (Debian's slurm-wlm and munge, installed if missing; needs root): an array job
# of two small `svgir capture` runs of the statue, one of them requeued mid-run as a preemption
# would, then checks that both finished with every result and that the requeued one resumed.
#
#   bash tools/slurm_check.sh [WORK]      (default WORK: /tmp/svgir-slurm)
#
# Needs ../shared/data/colmap/statue and a release build (`cargo build --release`).
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/.." && pwd)"
WORK="${1:-/tmp/svgir-slurm}"
STATUE="$ROOT/../shared/data/colmap/statue"
SVGIR="$ROOT/target/release/svgir"
[ -d "$STATUE" ] || { echo "error: $STATUE not found" >&2; exit 1; }
[ -x "$SVGIR" ] || { echo "error: $SVGIR not built (cargo build --release)" >&2; exit 1; }
if ! command -v slurmctld >/dev/null || ! command -v munged >/dev/null; then
  DEBIAN_FRONTEND=noninteractive apt-get install -y -q slurm-wlm munge >/dev/null
fi
rm -rf "$WORK" && mkdir -p "$WORK"/{spool,state,log,out}
host="$(hostname -s)"
cpus="$(nproc)"
cat > "$WORK/slurm.conf" <<EOF
ClusterName=svgir-check
SlurmctldHost=$host
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
StateSaveLocation=$WORK/state
SlurmdSpoolDir=$WORK/spool
SlurmctldPidFile=$WORK/slurmctld.pid
SlurmdPidFile=$WORK/slurmd.pid
SlurmctldLogFile=$WORK/log/slurmctld.log
SlurmdLogFile=$WORK/log/slurmd.log
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU
ReturnToService=2
MpiDefault=none
JobAcctGatherType=jobacct_gather/none
NodeName=$host CPUs=$cpus State=UNKNOWN
PartitionName=check Nodes=$host Default=YES MaxTime=INFINITE State=UP
EOF
export SLURM_CONF="$WORK/slurm.conf"
cleanup() {
  [ -f "$WORK/slurmd.pid" ] && kill "$(cat "$WORK/slurmd.pid")" 2>/dev/null || true
  [ -f "$WORK/slurmctld.pid" ] && kill "$(cat "$WORK/slurmctld.pid")" 2>/dev/null || true
}
trap cleanup EXIT
mkdir -p /run/munge && chmod 755 /run/munge
pgrep -x munged >/dev/null || munged --force
slurmctld -c
slurmd
for _ in $(seq 30); do sinfo -h -o %T 2>/dev/null | grep -qx idle && break; sleep 1; done
sinfo -h -o "%P %T %C" | tee "$WORK/sinfo.txt"
grep -q idle "$WORK/sinfo.txt" || { echo "error: the node did not come up (see $WORK/log)" >&2; exit 1; }

# Two captures: the statue under two names.
for name in statue_a statue_b; do ln -s "$STATUE" "$WORK/$name"; done
printf '%s\n' "$WORK/statue_a" "$WORK/statue_b" > "$WORK/captures.txt"
export SVGIR="$SVGIR"
export SVGIR_CAPTURE_FLAGS="--downscale 8 --iterations 300 --stage2-iterations 20 --relight-directions 16 --turntable 2 --device cpu"
cd "$WORK"
job="$(sbatch --parsable --array=0-1 --cpus-per-task=1 "$ROOT/tools/slurm/capture_array.sbatch" captures.txt out)"
echo "submitted array job $job"
# Preempt task 0 once it has written its first stage-1 checkpoint: requeue it.
for _ in $(seq 300); do [ -f out/statue_a/scene/checkpoint.bin ] && break; sleep 1; done
scontrol requeue "${job}_0" && echo "requeued ${job}_0 mid-run"
for _ in $(seq 1200); do [ -z "$(squeue -h -j "$job")" ] && break; sleep 2; done
[ -z "$(squeue -h -j "$job")" ] || { echo "error: job $job still queued after 40 min" >&2; exit 1; }

fail=0
for name in statue_a statue_b; do
  for f in report.html object/stage2/eval.json export/object.glb export/splats.glb object/viewer.html; do
    [ -f "out/$name/$f" ] || { echo "FAIL: out/$name/$f missing"; fail=1; }
  done
done
log_a="$(ls svgir-capture-"$job"_0.log)"
grep -q "restart 1" "$log_a" || { echo "FAIL: task 0 was not restarted ($log_a)"; fail=1; }
grep -q "resumed\|(done before)" "$log_a" || { echo "FAIL: task 0 did not resume ($log_a)"; fail=1; }
for name in statue_a statue_b; do
  python3 -c "import json,sys; e=json.load(open('out/$name/object/stage2/eval.json')); print('$name: PBR re-render', round(e['nvs']['psnr'],2), 'dB')"
done
[ "$fail" = 0 ] && echo "slurm_check: OK (both captures finished; the requeued one resumed)" || exit 1
