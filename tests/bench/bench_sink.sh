#!/usr/bin/env bash
# A two-way BEM ball sinking through a deep tank of still water to its drag-limited speed: the 42-vertex icosphere of
# radius 0.1 m (tests/data/bem_ico1.obj) at 1200 and 2000 kg/m³, let go at rest 0.25 m under the surface of a
# 0.5 × 1.5 × 0.5 m tank (Δx = 0.02 m, 5 cells per radius), 36 frames. Per frame: the ball's height and sinking speed;
# the terminal speed a sphere of the mesh's volume V and cross-section A reaches with the drag coefficient C_d = 0.47
# of Re ~ 10⁵, v_t = sqrt(2 (ρ_s − ρ_f) V g / (ρ_f C_d A)), for comparison (the grid resolves no boundary layer: its
# drag is the inviscid wake's at this resolution). The tank has no floor collider: the 2000 kg/m³ ball reaches the
# bottom near frame 21 and its later frames mean nothing. Measured: 1200 kg/m³ sinks at 0.24, 0.43, 0.58, 0.67, 0.78,
# 0.83 m/s after 0.25 … 1.5 s, still rising towards v_t = 1.03; 2000 kg/m³ at 0.81, 1.37, 1.70 m/s after 0.25, 0.5,
# 0.75 s (v_t = 2.31): the tank is too shallow for either to settle. CSV (default out/bench/sink.csv): density, frame,
# time, y, v; a Markdown table of the last frames on stdout.
set -u
cd "$(dirname "$0")/../.."
csv=${1:-out/bench/sink.csv}
mkdir -p "$(dirname "$csv")"
make -s bin/bake bin/precompute >/dev/null || exit 1
work=$(mktemp -d "${TMPDIR:-/tmp}/drench-bench-sink.XXXXXX")
trap 'rm -rf "$work"' EXIT
export DRENCH_CACHE="$work/cache"
# h5 FILE DATASET: its numbers in full precision, one line, separated by spaces
h5() { h5dump -y -w 0 -A 0 -m '%.17g' -d "$2" "$1" 2>/dev/null | awk '/DATA \{/{on=1; next} on && /^ *\}/{on=0} on { gsub(/,/, " "); printf "%s ", $0 } END { print "" }'; }
echo "density,frame,time,y,v" > "$csv"
echo "| density (kg/m³) | frames | speed at frame 24 / 30 / 36 (m/s) | v_t for C_d 0.47 (m/s) | bake seconds |"
echo "|---|---|---|---|---|"
for rho in 1200 2000; do
  cat > "$work/sink$rho.json" <<JSON
{ "shot": { "name": "sink$rho", "fps": 24, "frames": [1, 36], "gravity": [0, -9.81, 0] },
  "solver": { "cfl": 1.0, "max_substeps": 64 },
  "elements": [
    { "name": "water", "type": "liquid", "components": {
        "Domain": { "box": [[0, 0, 0], [0.5, 1.6, 0.5]], "voxel_size": 0.02 },
        "LiquidSource": { "box": [[0, 0, 0], [0.5, 1.5, 0.5]] }, "Particles": { "per_cell": 8, "seed": 3 } } },
    { "name": "ball", "type": "bem_solid", "components": { "Mesh": { "file": "$PWD/tests/data/bem_ico1.obj" },
        "Transform": { "translate": [0.25, 1.25, 0.25] },
        "LinearElastic": { "density": $rho, "shear_modulus": 1e6, "poisson": 0.4 }, "Compression": { "ratio": 1 },
        "BemSolver": { "time_step": 0.004166666666666667, "history_margin": 8 } } } ] }
JSON
  bin/precompute "$work/sink$rho.json" -j 2 >/dev/null 2>&1 || { echo "precompute failed" >&2; exit 1; }
  t=$EPOCHREALTIME
  bin/bake "$work/sink$rho.json" -j 2 --out "$work/out" -q >/dev/null 2>&1 || { echo "bake failed" >&2; exit 1; }
  secs=$(awk -v a="$t" -v b="$EPOCHREALTIME" 'BEGIN{printf "%.0f", b-a}')
  f1="$work/out/sink$rho/bake/frame.0001.h5"
  vol=$(h5 "$f1" /diagnostics/ball/volume | awk '{print $1}')
  speeds=""
  for f in $(seq 1 36); do
    ff=$(printf "%s/out/sink%s/bake/frame.%04d.h5" "$work" "$rho" "$f")
    y=$(h5 "$ff" /ball/translation | awk '{print $2}'); v=$(h5 "$ff" /ball/velocity | awk '{print -$2}')
    echo "$rho,$f,$(awk -v f="$f" 'BEGIN{printf "%.6f", f / 24}'),$y,$v" >> "$csv"
    case $f in 24|30|36) speeds="$speeds $(printf '%.3f' "$v")";; esac
  done
  vt=$(awk -v V="$vol" -v r="$rho" 'BEGIN { pi = 3.141592653589793; R = (3 * V / (4 * pi))^(1 / 3); A = pi * R * R
         printf "%.3f", sqrt(2 * (r - 1000) * V * 9.81 / (1000 * 0.47 * A)) }')
  echo "| $rho | 36 |$speeds | $vt | $secs |"
done
