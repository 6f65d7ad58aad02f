# Bad input: exit 2, a message naming file:line:col or element.component.field, nothing written under out/.
source "$(dirname "$0")/lib.sh"
bad="$ROOT/tests/data/bad"
nothing_written() { [ ! -e "$DRENCH_OUT" ] || [ -z "$(find "$DRENCH_OUT" -type f)" ]; }
run_bad() { # name pattern scene
  for st in bake mesh precompute; do
    expect_exit "$1 ($st)" 2 "$2" "$BIN/$st" "$3"
  done
  check "$1 writes nothing" nothing_written
}
run_bad "malformed JSON names file:line:col" "syntax\.json:[0-9]+:[0-9]+: error" "$bad/syntax.json"
run_bad "unknown component suggests a fix" "did you mean 'LiquidMaterial'" "$bad/unknown_component.json"
run_bad "negative density names element.component.field and range" "water\.LiquidMaterial\.density.*range" \
  "$bad/negative_density.json"
run_bad "missing asset names the path" "not found" "$bad/missing_asset.json"
run_bad "frames out of order" "out of order" "$bad/frames_order.json"
run_bad "a wind blowing out of its inflow face names element.component.field and the fix" \
  "gust\.Wind\.velocity: its x component \(-3 m/s\) points out of the box through face -x.*make it positive" \
  "$bad/air_wind_outward.json"
run_bad "air beside a liquid names both and says it is not supported yet" \
  "air element 'gust' and liquid element 'water' in one scene: air together with a liquid is not supported yet" \
  "$bad/air_with_liquid.json"
run_bad "a Drag field out of range names element.component.field and range" \
  "fur\.Drag\.tangent_scale = -1 is out of range \[0, 1000000\]" "$bad/drag_tangent_scale.json"
run_bad "Drag on hair in a scene without liquid or air names the element and the fix" \
  "fur\.Drag couples hair element 'fur' with the scene's fluid, but the scene has neither a liquid nor an air element; add a liquid or an air element, or remove Drag" \
  "$bad/drag_no_fluid.json"
run_bad "zero coupling iterations names solver.coupling_iterations and its range" \
  "coupling_iterations_zero\.json:3:[0-9]+: error: solver\.coupling_iterations = 0 is out of range \[1, 100\]" \
  "$bad/coupling_iterations_zero.json"
expect_exit "missing scene file" 2 "nope\.json" "$BIN/bake" "$WORK/nope.json"
# Assets whose content is bad are found when the bake loads them, still before anything is written.
mkdir -p "$WORK/scenes"
for m in empty nan broken; do
  sed "s#\"../meshes/cube.obj\"#\"$ROOT/assets/meshes/$m.obj\"#" "$ROOT/assets/scenes/small_dam.json" > "$WORK/scenes/$m.json"
  expect_exit "$m mesh asset is an error naming the file" 2 "$m\.obj" "$BIN/bake" "$WORK/scenes/$m.json"
done
check "bad assets write nothing" nothing_written
