# The default shot (assets/scenes/default.json: a furry ball dunked into a tank, lifted out and shaken, with the
# elastic jelly) through the pipeline's own checks, on a copy made small enough for the test (small_default.py: the
# cells twice as large, a tenth of the strands, its first 20 frames: the dunk, the hold and most of the lift).
# pipeline.sh runs all four stages without a warning, capture and dripping happen, the volume ledger closes every
# frame (and the render plots it), the film stays within Film.max_ratio, 1 and 2 threads and a resumed bake give the
# same bytes, a rerun runs nothing and an edit reruns exactly the stages it changes. Farm byte identity: test_farm.sh,
# on the same copy.
source "$(dirname "$0")/lib.sh"
full=$(stage_scene default.json)
scene="$WORK/scenes/shot.json"
python3 "$ROOT/tests/pipeline/small_default.py" "$full" "$scene" || { fail "the default shot is readable" "see above"; exit 0; }
shot=default_small
bake_dir="$DRENCH_OUT/$shot/bake"

says() { grep -q -- "$1" <<<"$out"; } # the last pipeline run's output has the line
out=$("$ROOT/pipeline.sh" --no-build "$scene" -j 2 2>&1); rc=$?
echo "$out" | grep -v ALF_PROGRESS | tail -4
check "the default shot runs through pipeline.sh" test "$rc" -eq 0
check "all four stages ran" says 'pipeline: 4 stage(s) ran'
check "20 frame caches, meshes and images" bash -c "[ \$(ls '$bake_dir'/frame.*.h5 | wc -l) -eq 20 ] &&
  [ \$(ls '$DRENCH_OUT/$shot/mesh'/water.*.obj | wc -l) -eq 20 ] && [ \$(ls '$DRENCH_OUT/$shot/render'/frame.*.png | wc -l) -eq 20 ]"
no_warning() { ! grep -i warn <<<"$out"; }
check "without a warning" no_warning
check "the render plots the volume ledger" test -s "$DRENCH_OUT/$shot/render/plots/volume_ledger.png"

# capture and dripping happened, the ledger closed every frame
ledger() {
  local f worst=0 cap=0 drip=0 line ratio=0
  for f in "$bake_dir"/frame.*.h5; do
    line=$(h5dump -A 0 -m %.17g -d /diagnostics/volume_ledger/relative_error -d /diagnostics/volume_ledger/captured \
             -d /diagnostics/volume_ledger/dripped "$f" 2>/dev/null | awk '/\(0\): /{ printf "%s ", $2 }')
    set -- $line
    [ $# -eq 3 ] || { echo "$f: no ledger"; return 1; }
    worst=$(awk -v e="$1" -v w="$worst" 'BEGIN { if (e < 0) e = -e; printf "%.3g", (e > w ? e : w) }')
    cap=$(awk -v a="$cap" -v b="$2" 'BEGIN { printf "%.9g", a + b }')
    drip=$(awk -v a="$drip" -v b="$3" 'BEGIN { printf "%.9g", a + b }')
  done
  echo "ledger: worst relative error $worst over 20 frames; captured $cap m^3, dripped $drip m^3"
  awk -v w="$worst" -v c="$cap" -v d="$drip" 'BEGIN { exit !(w <= 1e-9 && c > 0 && d > 0) }'
}
check "capture and dripping happen and the volume ledger closes every frame to 1e-9" ledger
# The limit holds where the film and capture apply it; the frame's H/r is measured after the strands' next solve,
# which changes a strand's length under its film's weight and contacts by ~1e-5 (E pi r^2 = 3 N here): 1e-4 of headroom.
film_within() {
  local f r
  for f in "$bake_dir"/frame.*.h5; do
    r=$(h5 "$f" /diagnostics/hair_film_max_ratio)
    awk -v r="$r" 'BEGIN { exit !(r + 0 > 0 && r <= 6 * (1 + 1e-4)) }' || { echo "$f: film H/r $r"; return 1; }
  done
}
check "the film never goes beyond Film.max_ratio (6)" film_within

# determinism: 1 and 2 threads, and a bake stopped after frame 12 (in the shake) and resumed
b1="$WORK/b1" b3="$WORK/b3"
"$BIN/bake" "$scene" -j 1 --out "$b1" -q >/dev/null 2>&1
check "the default shot on 1 and 2 threads is bit-identical" same_frames "$b1" "$DRENCH_OUT" "$shot" 20
"$BIN/bake" "$scene" -j 2 --frames 1-12 --out "$b3" -q >/dev/null 2>&1
"$BIN/bake" "$scene" -j 2 --out "$b3" --resume >"$WORK/resume.log" 2>&1
check "the default shot resumes after frame 12" grep -q "resuming after frame 12" "$WORK/resume.log"
check "a resumed bake of the default shot is bit-identical" same_frames "$b3" "$DRENCH_OUT" "$shot" 20

rerun() { "$ROOT/pipeline.sh" --no-build "$scene" -j 2 2>&1; }
out=$(rerun)
check "a rerun runs no stage" says 'pipeline: 0 stage(s) ran'
cp "$scene" "$WORK/shot.orig.json"
python3 - "$scene" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); s['render']['resolution'] = [320, 180]; json.dump(s, open(sys.argv[1], 'w'))
PY
out=$(rerun)
render_only() { says 'bake: up to date' && says 'mesh: up to date' && says 'render: running'; }
check "a render edit reruns render alone" render_only
python3 - "$scene" <<'PY'
import json, sys
s = json.load(open(sys.argv[1]))
for e in s['elements']:
    if e['type'] == 'hair': e['components']['Capture']['rate'] = 5
json.dump(s, open(sys.argv[1], 'w'))
PY
out=$(rerun)
after_precompute() { says 'precompute: up to date' && says 'bake: running' && says 'mesh: running' && says 'render: running'; }
check "a capture edit reruns bake, mesh and render but not precompute" after_precompute
cp "$WORK/shot.orig.json" "$scene"
