# Wet hair end to end (src/wet): the two hanging strands of the liquid–hair paper (assets/scenes/cylinder_2.json) clump
# under capillary bridges, a dry control does not; precompute builds the cohesion tables once (a second run is a cache
# hit) and bake without them exits 2 asking for precompute; no grid is built; the frame cache carries the film; a bake
# on 1 and 2 threads and a resumed one are bit-identical with bridges and film.
source "$(dirname "$0")/lib.sh"
scene=$(stage_scene cylinder_2.json)
bd="$DRENCH_OUT/cylinder_2/bake"

expect_exit "bake without the cohesion tables exits 2 asking for precompute" 2 "strands\.Cohesion.*run precompute" \
  "$BIN/bake" "$scene" --frames 1-2
check "and bakes nothing" bash -c "[ ! -e '$bd/frame.0001.h5' ]"
out=$("$BIN/precompute" "$scene" 2>&1)
check "precompute builds the two cohesion tables" grep -q "2 cohesion tables, 0 hits, 2 computed" <<<"$out"
check "the tables are in the cache" bash -c "[ \$(ls '$DRENCH_CACHE'/cohesion/*.h5 | wc -l) -eq 2 ]"
out=$("$BIN/precompute" "$scene" 2>&1)
check "a second precompute is a cache hit" grep -q "2 cohesion tables, 2 hits, 0 computed" <<<"$out"

out=$("$BIN/bake" "$scene" -j 2 2>&1); rc=$?
check "the wet scene bakes" test "$rc" -eq 0
check "it builds no grid" grep -q "world: 0 liquid grid(s), no MPM solver, 2 strand(s) of hair with 84 vertices" <<<"$out"

# the gap between the strands' tips (vertices 41 and 83) in frame f
tip_gap() { h5dump -y -w 0 -d /strands/position "$1" | awk '/DATA \{/{on=1; next} on && /\}/{on=0}
  on { gsub(/,/, " "); for (i = 1; i <= NF; i++) a[n++] = $i }
  END { t0 = 41 * 3; t1 = 83 * 3; printf "%.9g\n", sqrt((a[t1]-a[t0])^2 + (a[t1+1]-a[t0+1])^2 + (a[t1+2]-a[t0+2])^2) }'; }
# the rest distance of a bridged pair: radius_multiplier (1.6) times the contact distance 2r (100 µm)
rest=0.00016
settled=0
for f in $(seq 1 96); do
  g=$(tip_gap "$(printf '%s/frame.%04d.h5' "$bd" "$f")")
  awk -v g="$g" -v r="$rest" 'BEGIN { exit !(g > 1.1 * r) }' && settled=$((f + 1))
done
echo "the tips are within 1.1 x the rest distance (${rest} m) from frame $settled (t = $(awk -v f="$settled" 'BEGIN{printf "%.2f", f/24}') s) to the last"
check "the wet strands clump: tips within 1.1x the rest bridge distance by t = 3 s and together until t = 4 s" \
  bash -c "[ $settled -le 72 ]"
f1="$bd/frame.0001.h5"
check "the frame cache holds the film: liquid_area and film_thickness per vertex, with units" bash -c "
  h5dump -H -d /strands/liquid_area '$f1' | grep -q '( 84 )' && h5dump -a /strands/liquid_area/units '$f1' | grep -q 'm^2' &&
  h5dump -H -d /strands/film_thickness '$f1' | grep -q '( 84 )'"
check "and the film and pool volumes and the bridges in /diagnostics" bash -c "
  for d in hair_film_volume hair_pool_volume hair_bridges hair_solid_bridges hair_cross_flow; do
    h5dump -d /diagnostics/\$d '$bd/frame.0096.h5' >/dev/null 2>&1 || exit 1; done"
# the liquid stays: film + pools is the initial film to round-off
vol() { h5dump -m %.17g -d /diagnostics/hair_film_volume -d /diagnostics/hair_pool_volume "$1" | awk '/\(0\): [-0-9]/{s += $2} END{printf "%.17g\n", s}'; }
v1=$(vol "$f1"); v96=$(vol "$bd/frame.0096.h5")
check "film + pools keep their volume over 96 frames (to 1e-12)" \
  awk -v a="$v1" -v b="$v96" 'BEGIN { d = a - b; if (d < 0) d = -d; printf "film + pools %.17g m^3 at frame 1, %.17g at frame 96\n", a, b; exit !(d <= 1e-12 * a) }'
check "no NaN or Inf in any frame" bash -c "! (for f in '$bd'/frame.*.h5; do h5dump \"\$f\"; done | grep -Eiq '\\b(nan|inf)\\b')"

# the dry control: the same strands without Wetting keep their gap
dry="$WORK/scenes/cylinder_2_dry.json"
python3 - "$scene" "$dry" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); s['shot']['name'] = 'cylinder_2_dry'
c = s['elements'][0]['components']
for k in ('Wetting', 'Film', 'Cohesion'): c.pop(k, None)
json.dump(s, open(sys.argv[2], 'w'))
PY
"$BIN/bake" "$dry" -j 2 >/dev/null 2>&1
g=$(tip_gap "$DRENCH_OUT/cylinder_2_dry/bake/frame.0096.h5")
echo "dry control: tip gap $g m after 4 s (0.0005 at rest)"
check "a dry control keeps its gap within 5 %" awk -v g="$g" 'BEGIN { exit !(g >= 0.95 * 0.0005 && g <= 1.05 * 0.0005) }'

# 1 thread, 2 threads, and a bake stopped after frame 12 and resumed give the same bytes (bridges and film included)
short="$WORK/scenes/cylinder_2_short.json"
python3 - "$scene" "$short" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); s['shot']['name'] = 'cyl_short'; s['shot']['frames'] = [1, 24]
json.dump(s, open(sys.argv[2], 'w'))
PY
sd="$DRENCH_OUT/cyl_short/bake"
"$BIN/bake" "$short" -j 1 >/dev/null 2>&1; mkdir -p "$WORK/j1"; cp "$sd"/frame.*.h5 "$WORK/j1/"
"$BIN/bake" "$short" -j 2 >/dev/null 2>&1
check "1 and 2 threads give the same frames" bash -c "for f in '$WORK'/j1/frame.*.h5; do cmp -s \"\$f\" '$sd'/\$(basename \"\$f\") || exit 1; done"
"$BIN/bake" "$short" --frames 1-12 -j 2 >/dev/null 2>&1
"$BIN/bake" "$short" --resume -j 2 >/dev/null 2>&1
check "a bake resumed after frame 12 gives the same frames" bash -c "for f in '$WORK'/j1/frame.*.h5; do cmp -s \"\$f\" '$sd'/\$(basename \"\$f\") || exit 1; done"
bridges=$(h5dump -d /diagnostics/hair_bridges "$sd/frame.0012.h5" | awk '/\(0\): [0-9]/{print $2}')
check "the resumed state holds bridges ($bridges at frame 12)" test "${bridges:-0}" -gt 0
