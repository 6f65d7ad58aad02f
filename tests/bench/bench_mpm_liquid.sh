#!/usr/bin/env bash
# MPM solids two-way with the liquid against resolution: run time against error. A ball of radius 0.07 m (2 particles a
# cell per axis) in a 0.4 m tank, Δx = 0.04, 0.025, 0.02 and 0.0125 m (1.75 to 5.6 cells per radius; each divides the
# tank, so the water fills it wall to wall), one voxel size for liquid and MPM:
#   sink  — 2000 kg/m³ let go at rest in a 0.38 m deep pool: the mean acceleration over the first frame against
#           potential flow's g (ρ_s − ρ_f)/(ρ_s + ½ρ_f) = 3.924 m/s² (the tank's walls add a little added mass);
#   float — 500 kg/m³ pushed down at 0.3 m/s at the surface of a 0.2 m pool, 36 frames: the submerged fraction from the
#           ball's mean height c over frames 13–36 against the pool's level L = (V_p + m/ρ_f)/A_tank (V_p the liquid
#           volume the particles left after the seeding inside the ball was removed, plus the water the floating ball
#           displaces), f = ½ + π r² (L − c)/V with V = m/ρ_s and r from V; Archimedes gives ½. This level carries the
#           liquid's own volume error (the particles' nominal volume is not the volume the grid holds them at): 3 mm of
#           level is 0.035 of fraction here; tests/validation/test_world_mpm_liquid.c takes the level from the pressure
#           instead (0.508 at Δx = 0.02 m against 0.535 here).
#   terminal — after the sweep: a ball of radius 0.1 m at 1200 kg/m³ let go at rest 0.25 m under the surface of a
#           0.5 × 1.5 × 0.5 m tank (Δx = 0.02 m, 5 cells a radius, as bench_sink.sh's BEM ball), 48 frames: its sinking
#           speed against the drag-limited v_t = sqrt(2 (ρ_s − ρ_f) V g / (ρ_f C_d A)) with a sphere's C_d = 0.47
#           (Re ~ 1e5; the grid resolves no boundary layer, the tank's walls block 13 % of its section).
# CSV (default out/bench/mpm_liquid.csv): case, dx, cells_per_radius, particles, seconds, value, error (terminal: the
# speed in m/s at frames 24, 36 and 40 as value, its shortfall from v_t as error); a Markdown table.
set -u
cd "$(dirname "$0")/../.."
csv=${1:-out/bench/mpm_liquid.csv}
mkdir -p "$(dirname "$csv")"
make -s bin/bake >/dev/null || exit 1
work=$(mktemp -d "${TMPDIR:-/tmp}/drench-bench-mpm-liquid.XXXXXX")
trap 'rm -rf "$work"' EXIT
h5() { h5dump -y -w 0 -A 0 -m '%.17g' -d "$2" "$1" 2>/dev/null | awk '/DATA \{/{on=1; next} on && /^ *\}/{on=0} on { gsub(/,/, " "); printf "%s ", $0 } END { print "" }'; }
scene() { # NAME FRAMES DX DEPTH Y VY DENSITY
  cat > "$work/$1.json" <<JSON
{ "shot": { "name": "$1", "fps": 24, "frames": [1, $2], "gravity": [0, -9.81, 0] },
  "solver": { "cfl": 1.0, "max_substeps": 64 },
  "elements": [
    { "name": "water", "type": "liquid", "components": {
        "Domain": { "box": [[0, 0, 0], [0.4, 0.4, 0.4]], "voxel_size": $3 },
        "LiquidSource": { "box": [[0, 0, 0], [0.4, $4, 0.4]] }, "Particles": { "per_cell": 8, "seed": 3 } } },
    { "name": "ball", "type": "mpm_solid", "components": {
        "Domain": { "box": [[0, 0, 0], [0.4, 0.4, 0.4]], "voxel_size": $3 },
        "MpmShape": { "centre": [0.2, $5, 0.2], "radius": 0.07 }, "InitialVelocity": { "velocity": [0, $6, 0] },
        "MpmMaterial": { "model": "fixed_corotated", "density": $7, "youngs_modulus": 2e5, "poisson": 0.3 } } } ] }
JSON
}
bake() { # NAME -> seconds
  local t=$EPOCHREALTIME
  bin/bake "$work/$1.json" -j 2 --out "$work/out" -q >/dev/null 2>&1 || { echo "bake $1 failed" >&2; exit 1; }
  awk -v a="$t" -v b="$EPOCHREALTIME" 'BEGIN{printf "%.1f", b-a}'
}
fr() { printf "%s/out/%s/bake/frame.%04d.h5" "$work" "$1" "$2"; }
echo "case,dx,cells_per_radius,particles,seconds,value,error" > "$csv"
echo "| Δx (m) | cells per radius | MPM particles | sink: a / a_potential | seconds | float: submerged fraction | seconds |"
echo "|---|---|---|---|---|---|---|"
for dx in 0.04 0.025 0.02 0.0125; do
  cpr=$(awk -v d="$dx" 'BEGIN{printf "%.2f", 0.07 / d}')
  scene "sink" 1 "$dx" 0.38 0.2 0 2000
  s1=$(bake sink)
  n=$(h5 "$(fr sink 1)" /diagnostics/ball/particles | awk '{print $1}')
  a=$(h5 "$(fr sink 1)" /diagnostics/ball/linear_momentum | awk -v m="$(h5 "$(fr sink 1)" /diagnostics/ball/mass)" '{printf "%.6f", -$2 / m * 24}')
  ra=$(awk -v a="$a" 'BEGIN{printf "%.4f", a / (9.81 * 1000 / 2500)}')
  echo "sink,$dx,$cpr,$n,$s1,$ra,$(awk -v r="$ra" 'BEGIN{d = r - 1; printf "%.5f", d < 0 ? -d : d}')" >> "$csv"
  scene "float" 36 "$dx" 0.2 0.2 -0.3 500
  s2=$(bake float)
  m=$(h5 "$(fr float 1)" /diagnostics/ball/mass | awk '{print $1}')
  vn=$(h5 "$(fr float 1)" /diagnostics/water/particle_volume_nominal | awk '{print $1}')
  sum=0
  for f in $(seq 13 36); do sum=$(awk -v s="$sum" -v c="$(h5 "$(fr float "$f")" /diagnostics/ball/centre_of_mass)" 'BEGIN{split(c, x, " "); printf "%.10f", s + x[2]}'); done
  fv=$(awk -v s="$sum" -v m="$m" -v vn="$vn" 'BEGIN { pi = 3.141592653589793; c = s / 24; V = m / 500
        r = (3 * V / (4 * pi))^(1 / 3); L = (vn + m / 1000) / 0.16; printf "%.4f", 0.5 + pi * r * r * (L - c) / V }')
  echo "float,$dx,$cpr,$n,$s2,$fv,$(awk -v f="$fv" 'BEGIN{d = f / 0.5 - 1; printf "%.5f", d < 0 ? -d : d}')" >> "$csv"
  echo "| $dx | $cpr | $n | $ra | $s1 | $fv | $s2 |"
done

# the drag-limited speed in a deep tank
cat > "$work/terminal.json" <<JSON
{ "shot": { "name": "terminal", "fps": 24, "frames": [1, 48], "gravity": [0, -9.81, 0] },
  "solver": { "cfl": 1.0, "max_substeps": 64 },
  "elements": [
    { "name": "water", "type": "liquid", "components": {
        "Domain": { "box": [[0, 0, 0], [0.5, 1.6, 0.5]], "voxel_size": 0.02 },
        "LiquidSource": { "box": [[0, 0, 0], [0.5, 1.5, 0.5]] }, "Particles": { "per_cell": 8, "seed": 3 } } },
    { "name": "ball", "type": "mpm_solid", "components": {
        "Domain": { "box": [[0, 0, 0], [0.5, 1.6, 0.5]], "voxel_size": 0.02 },
        "MpmShape": { "centre": [0.25, 1.25, 0.25], "radius": 0.1 },
        "MpmMaterial": { "model": "fixed_corotated", "density": 1200, "youngs_modulus": 1e6, "poisson": 0.3 } } } ] }
JSON
s3=$(bake terminal)
m=$(h5 "$(fr terminal 1)" /diagnostics/ball/mass | awk '{print $1}')
vt=$(awk -v m="$m" 'BEGIN { pi = 3.141592653589793; V = m / 1200; R = (3 * V / (4 * pi))^(1 / 3)
       printf "%.4f", sqrt(2 * 200 * V * 9.81 / (1000 * 0.47 * pi * R * R)) }')
speeds=""
for f in 24 36 40; do
  v=$(h5 "$(fr terminal "$f")" /diagnostics/ball/linear_momentum | awk -v m="$m" '{printf "%.4f", -$2 / m}')
  echo "terminal,0.02,5.00,$(h5 "$(fr terminal 1)" /diagnostics/ball/particles | awk '{print $1}'),$s3,$v,$(awk -v v="$v" -v t="$vt" 'BEGIN{printf "%.4f", 1 - v / t}')" >> "$csv"
  speeds="$speeds $v"
done
echo
echo "| 1200 kg/m³, r = 0.1 m, Δx = 0.02 m | sinking speed at 1, 1.5, 1.67 s (m/s) | v_t for C_d 0.47 (m/s) | bake seconds |"
echo "|---|---|---|---|"
echo "| MPM ball |$speeds | $vt | $s3 |"
