# Every executable: --help, --version, --print-key, exit codes (DESIGN §1).
source "$(dirname "$0")/lib.sh"
scene="$ROOT/assets/scenes/small_dam.json"
for st in precompute bake mesh render; do
  check "$st --help exits 0" bash -c "'$BIN/$st' --help | grep -q usage"
  check "$st --version exits 0" bash -c "'$BIN/$st' --version | grep -q drench"
  check "$st --print-key prints 32 hex digits" bash -c "'$BIN/$st' --print-key '$scene' | grep -Eq '^[0-9a-f]{32}$'"
  expect_exit "$st unknown option exits 2" 2 "unknown option '--bogus'" "$BIN/$st" --bogus "$scene"
  expect_exit "$st without a scene exits 2" 2 "no scene given" "$BIN/$st"
done
expect_exit "render before mesh: missing mesh folder exits 2" 2 "mesh folder is missing" "$BIN/render" "$scene"
check "render wrote nothing without meshes" test ! -e "$DRENCH_OUT/small_dam/render"
expect_exit "render --finish with --frames exits 2" 2 "does not take --frames" "$BIN/render" "$scene" --finish --frames 1-2
expect_exit "bake does not take --finish" 2 "unknown option '--finish'" "$BIN/bake" "$scene" --finish
check "--print-frames prints the shot's range" bash -c "[ \"\$('$BIN/mesh' --print-frames '$scene')\" = '1 12' ] && [ \"\$('$BIN/mesh' --print-frames '$scene' --frames 3-5)\" = '3 5' ]"
expect_exit "bake --frames out of order exits 2" 2 "out of order" "$BIN/bake" "$scene" --frames 9-3
expect_exit "bake --frames outside the shot exits 2" 2 "outside the shot" "$BIN/bake" "$scene" --frames 1-400
expect_exit "bad -j exits 2" 2 "thread count" "$BIN/bake" "$scene" -j 0
# the threads' wait at barriers: a short spin by default (core.h), the user's setting when given
check "bake's threads spin briefly, then sleep, by default" bash -c \
  "'$BIN/bake' '$scene' --frames 1-1 --out '$WORK/wait' 2>&1 | grep -q 'GOMP_SPINCOUNT=3000'"
check "bake keeps the user's OpenMP wait policy" bash -c \
  "OMP_WAIT_POLICY=active '$BIN/bake' '$scene' --frames 1-1 --out '$WORK/wait' 2>&1 | grep -q 'OMP_WAIT_POLICY=active'"
check "list-components names every component" bash -c \
  "'$BIN/bake' --list-components | grep -q LiquidMaterial && '$BIN/bake' --list-components | grep -q Motion"
check "list-components gives units and ranges" bash -c "'$BIN/bake' --list-components | grep -E 'density' | grep -q 'kg/m'"
check "precompute says there is nothing to do" bash -c "'$BIN/precompute' '$scene' 2>&1 | grep -q 'nothing to do'"
check "nothing but MANIFEST written by precompute" bash -c "[ \"\$(ls '$DRENCH_OUT/small_dam/precompute')\" = MANIFEST ]"
check "precompute computes nothing into the cache" bash -c "[ ! -e '$DRENCH_CACHE' ] || [ -z \"\$(ls -A '$DRENCH_CACHE')\" ]"
readme_in_sync() {
  local want; want=$("$BIN/bake" --list-components --markdown | tail -n +2 | sed 's/^#### /###### /; s/^### /##### /; s/^## /#### /')
  local have; have=$(awk '/<!-- BEGIN COMPONENT REFERENCE -->/{on=1; next} /<!-- END COMPONENT REFERENCE -->/{on=0} on' "$ROOT/README.md")
  [ "$want" = "$have" ]
}
check "README component reference matches --list-components (make readme)" readme_in_sync
