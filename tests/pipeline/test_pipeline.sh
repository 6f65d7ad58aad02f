# pipeline.sh end to end on a small dam break: outputs, and cache invalidation reruns exactly what changed.
source "$(dirname "$0")/lib.sh"
scene=$(stage_scene small_dam.json)
mesh_dir="$DRENCH_OUT/small_dam/mesh"
out=$("$ROOT/pipeline.sh" --no-build "$scene" 2>&1); rc=$?
echo "$out" | tail -5
check "first run succeeds" test "$rc" -eq 0
check "first run runs all four stages" bash -c "echo '$out' | grep -q 'pipeline: 4 stage(s) ran'"
check "12 VDB frames" test "$(ls "$mesh_dir"/water.[0-9][0-9][0-9][0-9].vdb 2>/dev/null | wc -l)" -eq 12
check "12 OBJ frames" test "$(ls "$mesh_dir"/water.*.obj 2>/dev/null | wc -l)" -eq 12
check "collider exported once" test -f "$mesh_dir/block.obj"
check "12 frame caches" test "$(ls "$DRENCH_OUT"/small_dam/bake/frame.*.h5 | wc -l)" -eq 12
check "report.json written" grep -q '"status": "ok"' "$DRENCH_OUT/small_dam/bake/report.json"
check "progress.jsonl has a line per frame" test "$(wc -l < "$DRENCH_OUT/small_dam/bake/progress.jsonl")" -eq 12
check "no temporary files left" test -z "$(find "$DRENCH_OUT" -name '*.tmp.*')"
if command -v vdb_print >/dev/null; then
  check "vdb_print lists surface and vel" bash -c "vdb_print '$mesh_dir/water.0012.vdb' | grep -q surface && vdb_print '$mesh_dir/water.0012.vdb' | grep -q vel"
fi
if command -v h5dump >/dev/null; then
  check "h5dump shows units and the scene key" bash -c "h5dump -A '$DRENCH_OUT/small_dam/bake/frame.0001.h5' | grep -q scene_key && h5dump -A '$DRENCH_OUT/small_dam/bake/frame.0001.h5' | grep -q units"
fi
check "every OBJ reloads through assimp, closed liquid surfaces" "$ROOT/build/tests/objcheck" "$mesh_dir"/*.obj

rerun() { "$ROOT/pipeline.sh" --no-build "$scene" 2>&1; }
t=$EPOCHREALTIME; out=$(rerun); secs=$(awk -v a="$t" -v b="$EPOCHREALTIME" 'BEGIN{printf "%.2f", b-a}')
echo "no-op rerun took ${secs}s"
check "no-op rerun runs no stage" bash -c "echo '$out' | grep -q 'pipeline: 0 stage(s) ran'"

cp "$ROOT/tests/data/small_dam_reformatted.json" "$scene"
out=$(rerun)
check "reformatted JSON (whitespace, key order, 24 vs 24.0) changes no key" bash -c "echo '$out' | grep -q 'pipeline: 0 stage(s) ran'"

cp "$ROOT/assets/scenes/small_dam.json" "$scene"
sed -i 's/"smoothing": 1/"smoothing": 2/' "$scene"
out=$(rerun)
check "mesh change: bake up to date" bash -c "echo '$out' | grep -q 'bake: up to date'"
check "mesh change: mesh reruns" bash -c "echo '$out' | grep -q 'mesh: running'"

sed -i 's/"viscosity": 0.001/"viscosity": 0.002/' "$scene"
out=$(rerun)
check "viscosity change: precompute up to date" bash -c "echo '$out' | grep -q 'precompute: up to date'"
check "viscosity change: bake reruns" bash -c "echo '$out' | grep -q 'bake: running'"
check "viscosity change: mesh reruns" bash -c "echo '$out' | grep -q 'mesh: running'"

echo "# edited" >> "$WORK/meshes/cube.obj"
out=$(rerun)
check "collider asset bytes changed: bake reruns" bash -c "echo '$out' | grep -q 'bake: running'"

out=$("$ROOT/pipeline.sh" --no-build "$scene" --force mesh 2>&1)
check "--force mesh reruns mesh only" bash -c "echo '$out' | grep -q 'bake: up to date' && echo '$out' | grep -q 'mesh: running'"
out=$("$ROOT/pipeline.sh" --no-build "$scene" --from bake 2>&1)
check "--from bake reruns bake and mesh" bash -c "echo '$out' | grep -q 'bake: running' && echo '$out' | grep -q 'mesh: running'"

# A collider moved by Motion keys is exported in its scene pose once and posed in every frame.
moving="$ROOT/tests/data/moving_collider.json"
"$BIN/bake" "$moving" -q >/dev/null 2>&1 && "$BIN/mesh" "$moving" -q >/dev/null 2>&1
pd="$DRENCH_OUT/paddle/mesh"
check "moving collider: rest pose and 4 posed frames" bash -c "[ -f '$pd/paddle.obj' ] && [ \$(ls '$pd'/paddle.*.obj | wc -l) -eq 4 ]"
# keys move it 0.2 m along x over frames 0..4: frame 2 is halfway (0.1 m), frame 4 at 0.2 m
centre_x() { "$ROOT/build/tests/objcheck" "$1" | sed 's/.*centre \([^ ]*\).*/\1/'; }
check "moving collider: frame 2 halfway along its keys" awk -v c="$(centre_x "$pd/paddle.0002.obj")" 'BEGIN{exit !(c > 0.199 && c < 0.201)}'
check "moving collider: frame 4 at its last key" awk -v c="$(centre_x "$pd/paddle.0004.obj")" 'BEGIN{exit !(c > 0.299 && c < 0.301)}'
