# Hair end to end: a furry ball shaken about its vertical axis bakes, meshes and renders; the frame cache
# holds the strands as DESIGN §4 says; roots stay on the moving scalp; the scene builds no grid; hair
# stiffness re-bakes without precompute; bad hair input exits 2 before anything is written.
source "$(dirname "$0")/lib.sh"
scene="$ROOT/tests/data/hair_small.json"
bd="$DRENCH_OUT/hair_small/bake"; md="$DRENCH_OUT/hair_small/mesh"; rd="$DRENCH_OUT/hair_small/render"

t=$EPOCHREALTIME
out=$("$ROOT/pipeline.sh" --no-build "$scene" -j 2 2>&1); rc=$?
echo "$out" | grep -E '^(bake|mesh|render|pipeline): .*(frames|stage)' | grep -v running
awk -v a="$t" -v b="$EPOCHREALTIME" 'BEGIN{printf "pipeline on hair_small.json took %.1fs\n", b-a}'
check "pipeline runs all four stages on a hair scene" bash -c "[ $rc -eq 0 ] && grep -q 'pipeline: 4 stage(s) ran' <<<'$out'"
check "hair and a collider without liquid build no grid" \
  grep -q "world: 0 liquid grid(s), no MPM solver, 60 strand(s) of hair with 540 vertices, 1 collider SDF(s)" <<<"$out"
check "8 frame caches" test "$(ls "$bd"/frame.*.h5 2>/dev/null | wc -l)" -eq 8

f1="$bd/frame.0001.h5"
check "position V×3, velocity V×3, twist E, strand_offsets S+1, radius S" bash -c "
  h5dump -H -d /fur/position '$f1' | grep -q '( 540, 3 )' && h5dump -H -d /fur/velocity '$f1' | grep -q '( 540, 3 )' &&
  h5dump -H -d /fur/twist '$f1' | grep -q '( 480 )' && h5dump -H -d /fur/strand_offsets '$f1' | grep -q '( 61 )' &&
  h5dump -H -d /fur/radius '$f1' | grep -q '( 60 )'"
check "hair datasets carry units and the group its type" bash -c "h5dump -a /fur/position/units '$f1' | grep -q '\"m\"' &&
  h5dump -a /fur/twist/units '$f1' | grep -q rad && h5dump -a /fur/type '$f1' | grep -q hair"
check "strand offsets run from 0 to V in steps of 9" bash -c "h5dump -y -w 0 -d /fur/strand_offsets '$f1' |
  awk '/DATA \{/{on=1; next} on && /\}/{on=0} on { gsub(/,/, \" \"); for (i = 1; i <= NF; i++) { if (\$i != 9 * k) exit 1; k++ } } END { exit !(k == 61) }'"
check "no NaN or Inf in any frame" bash -c "! (for f in '$bd'/frame.*.h5; do h5dump \"\$f\"; done | grep -Eiq '\\b(nan|inf)\\b')"
check "progress.jsonl carries the hair diagnostics" \
  bash -c "[ \$(grep -c '\"hair_elastic_energy\"' '$bd/progress.jsonl') -eq 8 ] && grep -q '\"hair_cg_iterations\"' '$bd/progress.jsonl'"
check "report.json sums the hair solves" grep -q '"cg_iterations"' "$bd/report.json"
# kept for the cluster preconditioner's checks below (a later bake of a stiffer hair replaces this one)
cg_sum() { grep -o '"hair_cg_iterations":[0-9]*' "$1" | awk -F: '{ s += $2 } END { print s + 0 }'; }
positions() { h5dump -y -w 0 -d /fur/position "$1" | awk '/DATA \{/{on=1; next} on && /\}/{exit} on { gsub(/,/, " "); for (i = 1; i <= NF; i++) print $i }'; }
block_cg=$(cg_sum "$bd/progress.jsonl"); positions "$bd/frame.0008.h5" > "$WORK/block_x.txt"

# mesh: one polyline OBJ per frame, root first; ribbons on request
check "8 polyline OBJs with 60 strands each" bash -c "[ \$(ls '$md'/fur.*.obj | wc -l) -eq 8 ] &&
  for f in '$md'/fur.*.obj; do [ \$(grep -c '^l ' \"\$f\") -eq 60 ] || exit 1; done"
check "the polyline OBJ records the radius" grep -q '^# radius 0.0001' "$md/fur.0001.obj"
check "ribbons are written when mesh.hair_ribbons is on" bash -c "[ \$(ls '$md'/fur_ribbons.*.obj | wc -l) -eq 8 ]"
# the roots follow the shaken scalp: every root stays 0.049-0.050 m from the ball's centre (0, 0.2, 0), about which
# it turns (the icosphere's faces lie between 0.0488 and 0.05 of its vertices' radius)
roots_on_scalp() { awk '/^v /{n++; x[n]=$2; y[n]=$3; z[n]=$4} /^l /{r = sqrt(x[$2]^2 + (y[$2]-0.2)^2 + z[$2]^2);
                        if (r < 0.0487 || r > 0.05001) { print FILENAME ": root at " r; bad=1 } } END { exit bad }' "$@"; }
check "roots stay on the moving scalp in every frame" roots_on_scalp "$md"/fur.*.obj
check "the strands move" bash -c "! cmp -s '$md/fur.0001.obj' '$md/fur.0008.obj'"
check "8 PNG frames and a contact sheet" bash -c "[ \$(ls '$rd'/frame.*.png | wc -l) -eq 8 ] && [ -s '$rd/contact_sheet.png' ]"

# changing the hair's stiffness re-bakes, re-meshes and re-renders; precompute stays up to date
stiff="$WORK/hair_stiff.json"
sed 's#"youngs_modulus": 1e8#"youngs_modulus": 2e8#; s#"\.\./\.\./assets/#"'"$ROOT"'/assets/#g' "$scene" > "$stiff"
sed 's#"\.\./\.\./assets/#"'"$ROOT"'/assets/#g' "$scene" > "$WORK/hair_same.json"
"$ROOT/pipeline.sh" --no-build "$WORK/hair_same.json" -j 2 >/dev/null 2>&1
out=$("$ROOT/pipeline.sh" --no-build "$stiff" -j 2 2>&1)
check "a stiffer hair re-runs bake, mesh and render but not precompute" grep -q "pipeline: 3 stage(s) ran, 1 up to date" <<<"$out"

# bad input: exit 2 naming the file, element.Component.field and the fix; nothing baked
mk() { sed "$2"'; s#"name": "hair_small"#"name": "'"$1"'"#; s#"\.\./\.\./assets/#"'"$ROOT"'/assets/#g' "$scene" > "$WORK/$1.json"; }
mk bad_hair_radius 's#"radius": 1e-4#"radius": -1e-4#'
mk bad_hair_scalp 's#"scalp": "\.\./\.\./assets/meshes/sphere\.obj"#"scalp": "no_such_scalp.obj"#'
mk bad_hair_both 's#"count": 60#"curves": "'"$ROOT"'/tests/data/hair_curves.obj", "count": 60#'
expect_exit "a negative radius names the field and the range" 2 "bad_hair_radius\.json:[0-9]+:[0-9]+: error: fur\.RodMaterial\.radius = -0\.0001 is out of range" \
  "$BIN/bake" "$WORK/bad_hair_radius.json"
expect_exit "a missing scalp names the element, the field and the path" 2 "fur\.Groom\.scalp.*no_such_scalp\.obj" \
  "$BIN/bake" "$WORK/bad_hair_scalp.json"
expect_exit "scalp and curves together are refused" 2 "fur\.Groom.*scalp.*curves" "$BIN/bake" "$WORK/bad_hair_both.json"
check "bad hair input bakes nothing" bash -c "[ ! -e '$DRENCH_OUT/bad_hair_radius/bake' ] && [ ! -e '$DRENCH_OUT/bad_hair_scalp/bake' ] && [ ! -e '$DRENCH_OUT/bad_hair_both/bake' ]"

# HairSolver.preconditioner "cluster": strands joined by contacts are factored together; the same bake (to the
# solver's tolerance: the frame-8 positions differ by 3.5e-5 m, strands are 5 cm) in far fewer CG iterations (31
# against 269 with the default block preconditioner)
mk hair_cluster 's#"HairSolver": { "substeps": 4 }#"HairSolver": { "substeps": 4, "preconditioner": "cluster" }#'
cd_="$DRENCH_OUT/hair_cluster/bake"
"$BIN/bake" "$WORK/hair_cluster.json" -j 2 >/dev/null 2>&1; rc=$?
check "a cluster-preconditioned hair bake runs" bash -c "[ $rc -eq 0 ] && [ \$(ls '$cd_'/frame.*.h5 | wc -l) -eq 8 ]"
check "the cluster preconditioner takes at least 3 times fewer CG iterations than block" \
  test $((3 * $(cg_sum "$cd_/progress.jsonl"))) -le "$block_cg"
positions "$cd_/frame.0008.h5" > "$WORK/cluster_x.txt"
check "and gives the same strands to 0.2 mm at frame 8" awk 'NR == FNR { x[FNR] = $1; next }
  { d = x[FNR] - $1; if (d < 0) d = -d; if (d > m) m = d; n++ } END { exit !(n == 1620 && m < 2e-4) }' \
  "$WORK/block_x.txt" "$WORK/cluster_x.txt"
