#!/usr/bin/env bash
# The liquid-hair reference code's pure-liquid scenes rebuilt in drench (assets/scenes/box_test.json: 71k
# particles in a spherical bowl stirred by a paddle, 2 mm cells; assets/scenes/dragging_test.json: 119k
# particles in a rounded tank, 1.25 mm cells, with its strand — the strand does not act on the liquid
# yet), baked by bin/bake under drench's own CFL control with frame writes, as a user runs them.
# Reported per scene: wall seconds per simulated 5 ms (the reference's step: it took 0.262 s on box_test and
# 0.52 s on dragging_test per step on 2 quiet cores of this kind of machine) and the ratio to it, substeps
# per frame, the share of the bake's wall time the main thread spent on frame output, and the slowdown of a
# 2-thread bake with one busy process beside it, for drench's default OpenMP wait (a short spin, then
# sleep: core.h) and for waiting by spinning (OMP_WAIT_POLICY=active). Runs are interleaved and repeated; the table gives
# the fastest and the spread.
# usage: bench_reference.sh [csv = out/bench/reference.csv] [frames = 24]
set -u
cd "$(dirname "$0")/../.."
csv=${1:-out/bench/reference.csv}
frames=${2:-24}
repeats=${BENCH_REPEATS:-2}
work=$(mktemp -d "${TMPDIR:-/tmp}/drench-bench-ref.XXXXXX")
trap 'kill $busy 2>/dev/null; rm -rf "$work"' EXIT
busy=
mkdir -p "$(dirname "$csv")"

declare -A REF=([box_test]=0.262 [dragging_test]=0.52)

# bake SCENE OUT [ENV...]: prints wall seconds; the bake's report and progress stay in OUT
bake() {
  local scene=$1 out=$2; shift 2
  rm -rf "$out"
  local t0=$EPOCHREALTIME
  env "$@" bin/bake "assets/scenes/$scene.json" --frames 1-"$frames" -j 2 --out "$out" -q >"$out.log" 2>&1 ||
    { echo "bake of $scene failed:" >&2; tail -5 "$out.log" >&2; exit 1; }
  awk -v a="$t0" -v b="$EPOCHREALTIME" 'BEGIN { printf "%.3f", b - a }'
}

# stats OUT SCENE: "substeps_mean substeps_max io_main_seconds"
stats() {
  python3 - "$1/$2/bake" <<'PY'
import json, sys
d = sys.argv[1]
rows = [json.loads(l) for l in open(d + "/progress.jsonl")]
sub = [r.get("liquid_substeps", r["substeps"]) for r in rows]
io = sum(r["seconds"].get("io", 0.0) for r in rows)
print("%.2f %d %.3f" % (sum(sub) / len(sub), max(sub), io))
PY
}

spin() { ( while :; do :; done ) & busy=$!; }
unspin() { kill "$busy" 2>/dev/null; wait "$busy" 2>/dev/null; busy=; }

echo "scene,condition,repeat,wall_s,per_5ms_s,ratio_to_reference,substeps_mean,substeps_max,io_main_s,io_share" > "$csv"
for scene in box_test dragging_test; do
  sim=$(awk -v f="$frames" 'BEGIN { printf "%.6f", f / 24 }')
  for r in $(seq 1 "$repeats"); do
    for cond in quiet busy busy_active quiet_active; do
      envs=()
      case $cond in *active) envs=(OMP_WAIT_POLICY=active) ;; esac
      case $cond in busy*) spin ;; esac
      wall=$(bake "$scene" "$work/$scene-$cond" "${envs[@]+"${envs[@]}"}")
      case $cond in busy*) unspin ;; esac
      read -r smean smax io <<<"$(stats "$work/$scene-$cond" "$scene")"
      awk -v s="$scene" -v c="$cond" -v r="$r" -v w="$wall" -v sim="$sim" -v ref="${REF[$scene]}" -v sm="$smean" \
          -v sx="$smax" -v io="$io" 'BEGIN { p = w / (sim / 0.005);
          printf "%s,%s,%d,%.3f,%.4f,%.3f,%s,%s,%s,%.3f\n", s, c, r, w, p, p / ref, sm, sx, io, io / w }' >> "$csv"
    done
  done
done

python3 - "$csv" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
def best(scene, cond):
    rs = [r for r in rows if r["scene"] == scene and r["condition"] == cond]
    w = sorted(float(r["wall_s"]) for r in rs)
    return min(rs, key=lambda r: float(r["wall_s"])), w
print("| scene | condition | wall s (fastest; all) | s per simulated 5 ms | ratio to reference | liquid substeps/frame mean, max | main-thread output share |")
print("|---|---|---|---|---|---|---|")
for scene in ("box_test", "dragging_test"):
    for cond in ("quiet", "busy", "quiet_active", "busy_active"):
        r, w = best(scene, cond)
        print("| %s | %s | %s (%s) | %s | %s | %s, %s | %.1f %% |" % (scene, cond, r["wall_s"], ", ".join("%.1f" % x for x in w),
              r["per_5ms_s"], r["ratio_to_reference"], r["substeps_mean"], r["substeps_max"], 100 * float(r["io_share"])))
print()
print("| scene | slowdown beside a busy process, drench's default wait (a short spin, then sleep) | same, OMP_WAIT_POLICY=active |")
print("|---|---|---|")
for scene in ("box_test", "dragging_test"):
    q = best(scene, "quiet")[0]; b = best(scene, "busy")[0]
    qa = best(scene, "quiet_active")[0]; ba = best(scene, "busy_active")[0]
    print("| %s | %.2f× | %.2f× |" % (scene, float(b["wall_s"]) / float(q["wall_s"]), float(ba["wall_s"]) / float(qa["wall_s"])))
PY
