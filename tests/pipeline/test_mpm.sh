# MPM solids end to end: an elastic sphere dropped onto the floor of its domain bakes, meshes and renders; it
# falls, comes to rest on the floor with bounded energy and no NaN; two bodies on one grid with a collider and a
# mesh shape; only the solvers a scene needs are built; bad MPM input exits 2 before anything is baked.
source "$(dirname "$0")/lib.sh"
scene="$ROOT/tests/data/mpm_drop.json"
bd="$DRENCH_OUT/mpm_drop/bake"; md="$DRENCH_OUT/mpm_drop/mesh"; rd="$DRENCH_OUT/mpm_drop/render"

t=$EPOCHREALTIME
out=$("$ROOT/pipeline.sh" --no-build "$scene" -j 2 2>&1); rc=$?
echo "$out" | grep -E '^(bake|mesh|render|pipeline): .*(frames|stage)' | grep -v running
awk -v a="$t" -v b="$EPOCHREALTIME" 'BEGIN{printf "pipeline on mpm_drop.json took %.1fs\n", b-a}'
check "pipeline runs all four stages on an MPM scene" bash -c "[ $rc -eq 0 ] && grep -q 'pipeline: 4 stage(s) ran' <<<'$out'"
check "an MPM-only scene builds no liquid grid" grep -q "world: 0 liquid grid(s), one MPM grid with" <<<"$out"
check "16 frame caches" test "$(ls "$bd"/frame.*.h5 2>/dev/null | wc -l)" -eq 16
check "16 OBJ and 16 VDB surfaces of the body" \
  bash -c "[ \$(ls '$md'/jelly.*.obj | wc -l) -eq 16 ] && [ \$(ls '$md'/jelly.[0-9][0-9][0-9][0-9].vdb | wc -l) -eq 16 ]"
check "16 PNG frames and a contact sheet" bash -c "[ \$(ls '$rd'/frame.*.png | wc -l) -eq 16 ] && [ -s '$rd/contact_sheet.png' ]"
check "the body moves in the images" bash -c "! cmp -s '$rd/frame.0001.png' '$rd/frame.0016.png'"
check "every body surface is closed and reloads" "$ROOT/build/tests/objcheck" "$md"/jelly.*.obj
check "progress.jsonl carries the MPM diagnostics" \
  bash -c "[ \$(grep -c '\"mpm_elastic_energy\"' '$bd/progress.jsonl') -eq 16 ] && grep -q '\"mpm_cg_iterations\"' '$bd/progress.jsonl'"
check "report.json sums the MPM solves" grep -q '"newton_iterations"' "$bd/report.json"

# the frame cache layout of DESIGN §4, with units
f1="$bd/frame.0001.h5"; f16="$bd/frame.0016.h5"
header=$(h5dump -H "$f1")
check "position N×3, velocity, affine and deformation_gradient N×3×3, volume N" bash -c "
  n=\$(h5dump -H -d /jelly/position '$f1' | grep -o 'SIMPLE { ( [0-9]*, 3 )' | grep -o '[0-9][0-9]*' | head -1)
  [ -n \"\$n\" ] && [ \"\$n\" -gt 100 ] &&
  h5dump -H -d /jelly/velocity '$f1' | grep -q \"( \$n, 3 )\" &&
  h5dump -H -d /jelly/affine '$f1' | grep -q \"( \$n, 3, 3 )\" &&
  h5dump -H -d /jelly/deformation_gradient '$f1' | grep -q \"( \$n, 3, 3 )\" &&
  h5dump -H -d /jelly/volume '$f1' | grep -q \"( \$n )\""
check "datasets carry units" bash -c "h5dump -a /jelly/position/units '$f1' | grep -q '\"m\"' &&
  h5dump -a /jelly/deformation_gradient/units '$f1' | grep -q '\"1\"' && h5dump -a /jelly/volume/units '$f1' | grep -q 'm^3'"
check "the body's group says it is an mpm_solid" bash -c "h5dump -a /jelly/type '$f1' | grep -q mpm_solid"
check "no NaN or Inf in any frame" bash -c "! (for f in '$bd'/frame.*.h5; do h5dump \"\$f\"; done | grep -Eiq '\\b(nan|inf)\\b')"

# centroid of the particles (equal masses: the mean position) straight from the position datasets
centroid_y() { h5dump -y -w 0 -d /jelly/position "$1" | awk '/DATA \{/{on=1; next} on && /\}/{on=0} on {
    gsub(/,/, " "); for (i = 1; i <= NF; i++) { k++; if (k % 3 == 2) { s += $i; n++ } } } END { printf "%.6f", s / n }'; }
y1=$(centroid_y "$f1"); y15=$(centroid_y "$bd/frame.0015.h5"); y16=$(centroid_y "$f16")
echo "centroid height: frame 1 $y1 m, frame 15 $y15 m, frame 16 $y16 m (radius 0.05 m, released at 0.12 m)"
# resting on the floor: the centroid one radius up, give or take the sag under gravity and the grid's contact gap
# (MPM stops a body within about half a cell of a wall): 0.04 .. 0.07 m; and still: < 1 mm between the last frames
check "the body falls" awk -v a="$y1" -v b="$y16" 'BEGIN{exit !(b < a - 0.03)}'
check "the body rests on the floor" awk -v b="$y16" 'BEGIN{exit !(b > 0.04 && b < 0.07)}'
check "the body has come to rest" awk -v a="$y15" -v b="$y16" 'BEGIN{d = a - b; if (d < 0) d = -d; exit !(d < 0.001)}'
scalar() { h5dump -y -d "$2" "$1" | awk '/DATA \{/{getline; gsub(/[ ,]/, ""); print; exit}'; }
e1=$(scalar "$f1" /diagnostics/mpm_total_energy); ke16=$(scalar "$f16" /diagnostics/mpm_kinetic_energy)
emax=$(for f in "$bd"/frame.*.h5; do scalar "$f" /diagnostics/mpm_total_energy; done | sort -g | tail -1)
echo "energy: total at frame 1 $e1 J, largest total $emax J, kinetic at frame 16 $ke16 J"
# midpoint conserves energy up to the solver tolerances and the inelastic floor only removes it: the total
# (kinetic + elastic + gravity) never grows by more than 1 % of its start
check "energy stays bounded" awk -v a="$e1" -v m="$emax" 'BEGIN{exit !(m <= a * 1.01 + 1e-9)}'
check "little kinetic energy is left" awk -v a="$e1" -v k="$ke16" 'BEGIN{exit !(k < 0.01 * a)}'
vol=$("$ROOT/build/tests/objcheck" "$md/jelly.0016.obj" | sed 's/.*volume \([^ ]*\) .*/\1/')
# the surface wraps the sampled sphere (4/3 π 0.05³ = 5.2e-4 m³) at 0.8 particle spacings: 5e-4 .. 8e-4 m³
check "the resting surface keeps the body's volume" awk -v v="$vol" 'BEGIN{exit !(v > 5e-4 && v < 8e-4)}'

# two bodies on one grid (the union of their domains), a mesh shape, a static collider
pair="$ROOT/tests/data/mpm_pair.json"
out=$("$BIN/bake" "$pair" -j 2 2>&1); rc=$?
check "two bodies, a mesh shape and a collider bake" bash -c "[ $rc -eq 0 ] && grep -q 'one MPM grid with [0-9]* particles in 2 bodies, no hair, 1 collider SDF' <<<'$out'"
pf="$DRENCH_OUT/mpm_pair/bake/frame.0002.h5"
count() { h5dump -H -d "/$1/position" "$pf" | grep -o 'SIMPLE { ( [0-9]*' | grep -o '[0-9]*$'; }
# sphere.obj scaled to r = 0.05 m sampled at spacing 0.0125 m: 4/3 π 0.05³ / 0.0125³ = 268 particles, ±10 %
check "the mesh shape is filled" awk -v n="$(count ball)" 'BEGIN{exit !(n > 241 && n < 295)}'
# the 0.1 × 0.05 × 0.1 m brick, turned 30° about y, at spacing 0.0125: 4 layers of 0.01 m² / 0.0125² = 256, ±10 %
check "the rotated box is filled" awk -v n="$(count brick)" 'BEGIN{exit !(n > 230 && n < 282)}'
check "the ball keeps moving right (InitialVelocity 0.5 m/s)" awk -v p="$(h5dump -y -d /diagnostics/ball/linear_momentum "$pf" | awk '/DATA \{/{getline; sub(/,.*/, ""); print; exit}')" 'BEGIN{exit !(p > 0)}'

# a moving collider is posed every substep and meets the bodies with its surface velocity (the solver's
# contacts are tested in tests/stress/test_mpm_stress.c)
moving="$WORK/mpm_moving.json"
sed 's#"Transform": { "translate": \[0.25, 0.03, 0.15\], "scale": 0.06 } }#"Transform": { "translate": [0.25, 0.03, 0.15], "scale": 0.06 },\n                      "Motion": { "keys": [[0, 0, 0, 0, 0, 0, 0], [2, 0, 0.02, 0, 0, 0, 0]] } }#; s#"name": "mpm_pair"#"name": "mpm_moving"#; s#"\.\./\.\./assets/#"'"$ROOT"'/assets/#g' "$pair" > "$moving"
out=$("$BIN/bake" "$moving" --frames 1-1 -j 2 2>&1); rc=$?
check "a moving collider bakes with the MPM solids" bash -c "[ $rc -eq 0 ] && [ -f '$DRENCH_OUT/mpm_moving/bake/frame.0001.h5' ]"

# skip what a scene doesn't need: a liquid scene allocates nothing MPM and writes no MPM data
out=$("$BIN/bake" "$ROOT/assets/scenes/small_dam.json" --frames 1-1 -j 2 2>&1)
check "a scene without mpm_solid builds no MPM solver" grep -q "world: 1 liquid grid(s), no MPM solver" <<<"$out"
check "a liquid frame cache has no MPM data" bash -c "! h5dump -H '$DRENCH_OUT/small_dam/bake/frame.0001.h5' | grep -q mpm"
check "a liquid progress line has no MPM keys" bash -c "! grep -q mpm '$DRENCH_OUT/small_dam/bake/progress.jsonl'"

# bad input: exit 2 naming the file, element.Component.field and the fix; nothing under out/<shot>/bake
bad="$ROOT/tests/data/bad"
no_bake() { [ ! -e "$DRENCH_OUT/$1/bake" ]; }
for st in bake mesh precompute; do
  expect_exit "unknown MPM field suggests the name ($st)" 2 "mpm_unknown_field\.json:8:[0-9]+: error: jelly\.MpmMaterial: unknown field 'poison'; did you mean 'poisson'" \
    "$BIN/$st" "$bad/mpm_unknown_field.json"
  expect_exit "poisson 0.5 names the field and the range ($st)" 2 "mpm_poisson\.json:[0-9]+:[0-9]+: error: jelly\.MpmMaterial\.poisson = 0\.5 is out of range \[0, 0\.5\); use a ratio below 0\.5" \
    "$BIN/$st" "$bad/mpm_poisson.json"
  expect_exit "negative density names the field and the range ($st)" 2 "mpm_negative_density\.json:[0-9]+:[0-9]+: error: jelly\.MpmMaterial\.density = -1000 is out of range \[1, 100000\] kg/m\^3; use a positive density" \
    "$BIN/$st" "$bad/mpm_negative_density.json"
  expect_exit "a missing shape mesh names the path ($st)" 2 "mpm_missing_mesh\.json:[0-9]+:[0-9]+: error: jelly\.MpmShape\.mesh: asset 'meshes/no_such_jelly\.obj' not found.*fix the path" \
    "$BIN/$st" "$bad/mpm_missing_mesh.json"
  expect_exit "mismatched Transfer names both elements and the field ($st)" 2 "mpm_transfer_mismatch\.json:[0-9]+:[0-9]+: error: cube\.Transfer\.scheme = 'flip' differs from jelly\.Transfer\.scheme = 'apic'.*give both elements the same Transfer\.scheme" \
    "$BIN/$st" "$bad/mpm_transfer_mismatch.json"
done
# an open mesh is found when the bake loads it, still before anything is written
expect_exit "an open shape mesh names the file, the field and the fix" 2 "mpm_open_mesh\.obj: error: jelly\.MpmShape\.mesh: the mesh is not closed.*close the mesh" \
  "$BIN/bake" "$bad/mpm_open_mesh.json"
check "bad MPM input bakes nothing" bash -c "$(declare -f no_bake); no_bake bad_mpm_field && no_bake bad_mpm_poisson && no_bake bad_mpm_density && no_bake bad_mpm_missing_mesh && no_bake bad_mpm_transfer && no_bake bad_mpm_open_mesh"
# Transfer is shared with the liquid, whose MAC grid takes neither rpic nor another kernel than quadratic
stage_scene small_dam.json >/dev/null
sed 's/"LiquidMaterial": { "viscosity": 0.001 } } },/"LiquidMaterial": { "viscosity": 0.001 }, "Transfer": { "kernel": "cubic" } } },/' \
  "$ROOT/assets/scenes/small_dam.json" > "$WORK/scenes/cubic_liquid.json"
expect_exit "a liquid refuses an MPM-only kernel" 2 "cubic_liquid\.json:[0-9]+:[0-9]+: error: water\.Transfer\.kernel = 'cubic' is for mpm_solid elements.*quadratic" \
  "$BIN/bake" "$WORK/scenes/cubic_liquid.json"
