#!/usr/bin/env bash
# Coupled hair–fluid benchmark, 2 threads, each scene baked at solver.coupling_iterations 1 to 5 with
# coupling_tolerance 1e-12 (so every step takes them all):
#   fur_tank       assets/scenes/fur_tank.json: 300 strands × 9 vertices on a ball swept through a tank of 46,000
#                  particles on a 30×20×16 grid, frames 1–3;
#   fur_wind       assets/scenes/fur_wind.json: the same fur held in the air element's wind (24×20×16 cells of 1 cm,
#                  ramping to 4 m/s over 0.5 s), frames 1–12;
#   dragging_test  assets/scenes/dragging_test.json (one 42-vertex strand dragged through ~119k particles on a 64×64×14
#                  grid of 1.25 mm, the reference liquid–hair code's scene) with a Drag component on the strand,
#                  frames 1–6 (the strand starts moving at frame 2.4).
# Per run: the clock steps (coupled steps, from the frame caches' /diagnostics), seconds per step (the frame loop's wall
# time from progress.jsonl over the steps: start-up excluded) and per simulated second, the iterations taken, the
# largest final relative change of a step, the hair's velocities at the last frame against the 5-iteration run's (the
# change the iterations still make), the bake's whole wall time, and for dragging_test the ratio against the reference
# code's 2.0 s wall per 0.004 s step (500 s per simulated second) on 2 cores of this kind of machine.
# CSV (default out/bench/couple.csv) and a Markdown table on stdout.
# usage: bench_couple.sh [csv = out/bench/couple.csv] [fur_tank frames = 3] [fur_wind frames = 12] [dragging frames = 6]
set -u
cd "$(dirname "$0")/../.."
csv=${1:-out/bench/couple.csv}
mkdir -p "$(dirname "$csv")"
make -s bin/bake >/dev/null || exit 1
work=$(mktemp -d "${TMPDIR:-/tmp}/drench-bench-couple.XXXXXX")
trap 'rm -rf "$work"' EXIT
REF_STEP=2.0 REF_DT=0.004

h5first() { h5dump -d "$2" "$1" | awk '/\(0\):/{print $2; exit}' | tr -d ','; }
h5values() { h5dump -m "%.17g" -d "$2" -y -w 0 "$1" | grep -E '^ *[-0-9]' | tr -d ' ' | tr ',' '\n' | grep -v '^$'; }

# scene_at NAME K: the scene NAME at K coupling iterations (tolerance 1e-12), meshes by absolute path
scene_at() {
  local out="$work/$1.$2.json"
  case $1 in
    fur_tank|fur_wind)
      sed -e "s/\"coupling_iterations\": 3, \"coupling_tolerance\": [0-9.e-]*/\"coupling_iterations\": $2, \"coupling_tolerance\": 1e-12/" \
          -e "s#\"../meshes/#\"$PWD/assets/meshes/#g" "assets/scenes/$1.json" > "$out" ;;
    dragging_test)
      sed -e "s/\"max_substeps\": 64 }/\"max_substeps\": 64, \"coupling_iterations\": $2, \"coupling_tolerance\": 1e-12 }/" \
          -e 's/"HairSolver": { "substeps": 10 }/"Drag": {}, "HairSolver": { "substeps": 10 }/' \
          -e "s#\"../meshes/#\"$PWD/assets/meshes/#g" "assets/scenes/$1.json" > "$out" ;;
  esac
  grep -q "\"coupling_iterations\": $2," "$out" && grep -q '"Drag"' "$out" || { echo "bench_couple: could not set up $1" >&2; exit 1; }
  echo "$out"
}

echo "scene,iterations,frames,steps,seconds_per_step,seconds_per_sim_second,iterations_taken,change_max,hair_velocity_diff,wall_s,ratio_to_reference_step,ratio_to_reference_sim" > "$csv"
# run NAME HAIR_ELEMENT FRAMES
run() {
  local name=$1 hair=$2 frames=$3 k
  for k in 5 1 2 3 4; do
    local s o t0 t1
    s=$(scene_at "$name" "$k"); o="$work/$name.o$k"
    t0=$EPOCHREALTIME
    bin/bake "$s" --frames 1-"$frames" --out "$o" -q -j 2 >"$o.log" 2>&1 || { echo "bench_couple: bake of $name failed" >&2; tail -3 "$o.log" >&2; exit 1; }
    t1=$EPOCHREALTIME
    local steps=0 its=0 ch=0 i g n c st
    for i in $(seq 1 "$frames"); do
      g=$(printf "%s/%s/bake/frame.%04d.h5" "$o" "$name" "$i")
      st=$(h5first "$g" /diagnostics/coupling_steps); n=$(h5first "$g" /diagnostics/coupling_iterations)
      c=$(h5first "$g" /diagnostics/coupling_change_max)
      steps=$((steps + st)); its=$((its + n))
      ch=$(awk -v a="$ch" -v b="$c" 'BEGIN{print (b > a) ? b : a}')
    done
    local loop
    loop=$(python3 -c "import json,sys; print(sum(json.loads(l)['seconds']['frame'] for l in open(sys.argv[1])))" \
           "$o/$name/bake/progress.jsonl")
    h5values "$(printf "%s/%s/bake/frame.%04d.h5" "$o" "$name" "$frames")" "/$hair/velocity" > "$work/$name.v$k"
    local diff
    diff=$(paste "$work/$name.v$k" "$work/$name.v5" | awk '{d = $1 - $2; if (d < 0) d = -d; if (d > m) m = d} END{print m + 0}')
    awk -v nm="$name" -v k="$k" -v f="$frames" -v st="$steps" -v loop="$loop" -v its="$its" -v ch="$ch" -v d="$diff" \
        -v a="$t0" -v b="$t1" -v rs="$REF_STEP" -v rdt="$REF_DT" 'BEGIN {
          sps = loop / st; sim = loop / (f / 24)
          r1 = (nm == "dragging_test") ? sprintf("%.3f", sps / rs) : ""
          r2 = (nm == "dragging_test") ? sprintf("%.3f", sim / (rs / rdt)) : ""
          printf "%s,%d,%d,%d,%.4f,%.2f,%d,%.3e,%.3e,%.2f,%s,%s\n", nm, k, f, st, sps, sim, its, ch, d, b - a, r1, r2 }' >> "$csv"
  done
}
run fur_tank fur "${2:-3}"
run fur_wind fur "${3:-12}"
run dragging_test strand "${4:-6}"

echo "| scene | coupling iterations | frames | clock steps | s per step (wall, 2 threads) | s per simulated s | iterations taken (per step) | largest final change | max hair velocity diff vs 5 iterations (m/s) | bake wall s | vs reference s/step | vs reference s per simulated s |"
echo "|---|---|---|---|---|---|---|---|---|---|---|---|"
tail -n +2 "$csv" | sort -t, -k1,1 -k2,2n | awk -F, '{
  printf "| %s | %s | %s | %s | %.3f | %.1f | %s (%.2f) | %.2e | %.2e | %.1f | %s | %s |\n",
         $1, $2, $3, $4, $5, $6, $7, $7 / $4, $8, $9, $10, ($11 == "" ? "" : $11 "×"), ($12 == "" ? "" : $12 "×") }'
