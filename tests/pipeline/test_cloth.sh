# Cloth end to end (src/cloth, world_cloth.c) on a reduced copy of the shipped cloth_dip shot (a 0.3 m towel of
# 33 x 33 vertices pinned along its top edge, dipped into a tank by its Motion and held there; ClothDrag couples it
# with the water): it bakes without a warning; the pinned vertices land exactly where the Motion puts them; the coupled
# loop's momentum ledger (what the cloth received + what the water was given) is zero to round-off every frame; a bake
# begun on 1 thread and resumed on 2 is bit-identical to one on 2; mesh writes towel.NNNN.obj with a normal per vertex and render draws
# it with the mesh file's texture coordinates (self contact off in these copies: the towel crumpling in the water
# makes hundreds of contacts between far-numbered vertices, which cost CG iterations in every coupled solve, 10× the
# bake; test_cloth covers self contact); a sheet rests on a bem_solid and on an mpm_solid. Then a reduced cloth_flag (the panel in the air's wind) bakes without a warning and the wind carries the flag
# downstream; and bad cloth input exits 2 naming the element, the field and the fix, with no frame written.
source "$(dirname "$0")/lib.sh"
full=$(stage_scene cloth_dip.json)
S="$WORK/scenes"
scene="$S/dip.json"
python3 - "$full" "$scene" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); s['shot']['name'] = 'dip'; s['shot']['frames'] = [1, 12]
s['elements'][0]['components']['Domain']['voxel_size'] = 0.04
s['elements'][0]['components']['Particles']['per_cell'] = 4
t = s['elements'][1]['components']
t['Motion']['keys'] = [[0, 0, 0, 0, 0, 0, 0], [2, 0, 0, 0, 0, 0, 0], [10, 0, -0.24, 0, 0, 0, 0], [12, 0, -0.24, 0, 0, 0, 0]]
t['ClothSolver'] = {'substeps': 8}
t['ClothMaterial']['self_contact'] = False  # what is checked here is the coupling; self contact has its own tests
json.dump(s, open(sys.argv[2], 'w'))
PY
b2="$WORK/b2" b3="$WORK/b3"
fr() { printf '%s/dip/bake/frame.%04d.h5' "$1" "$2"; }

t0=$(date +%s.%N)
"$BIN/bake" "$scene" -j 2 --out "$b2" >"$WORK/bake.log" 2>&1; rc=$?
t1=$(date +%s.%N)
check "the dipped towel bakes" test "$rc" -eq 0
echo "bake: $(awk -v a="$t0" -v b="$t1" 'BEGIN{printf "%.1f", b - a}') s on 2 threads"
check "without a warning" bash -c "! grep -qi warn '$WORK/bake.log'"

# the pinned top edge (rest y in [0.55, 0.6]: three rows of 33) follows the Motion exactly: 0.24 m lower at frame 12
pins() {
  local rest now
  rest=$(h5 "$(fr "$b2" 1)" /towel/position)
  now=$(h5 "$(fr "$b2" 12)" /towel/position)
  paste <(echo "$rest" | tr ' ' '\n' | awk 'NF' | paste - - -) <(echo "$now" | tr ' ' '\n' | awk 'NF' | paste - - -) |
    awk '$2 >= 0.55 { n++; d = $5 - ($2 - 0.24); if (d < 0) d = -d; if (d > w) w = d; s += $5 - $2 }
         END { printf "%d pinned vertices, mean drop %.9f m, largest miss %.3g m\n", n, -s / n, w; exit !(n == 99 && w < 1e-9) }'
}
check "the pinned vertices land where the Motion puts them (within 1e-9 m)" pins
sank() {
  local y1 y12
  y1=$(h5 "$(fr "$b2" 1)" /towel/position | tr ' ' '\n' | awk 'NF { k++; if (k % 3 == 2) { s += $1; n++ } } END { print s / n }')
  y12=$(h5 "$(fr "$b2" 12)" /towel/position | tr ' ' '\n' | awk 'NF { k++; if (k % 3 == 2) { s += $1; n++ } } END { print s / n }')
  echo "mean height: frame 1 $y1 m, frame 12 $y12 m"
  awk -v a="$y1" -v b="$y12" 'BEGIN { exit !(a - b > 0.15) }'
}
check "the towel went into the water" sank
ledger() {
  local f a h l worst=0
  for f in $(seq 1 12); do
    for a in x y z; do
      h=$(h5 "$(fr "$b2" "$f")" /diagnostics/coupling_impulse_hair_$a); l=$(h5 "$(fr "$b2" "$f")" /diagnostics/coupling_impulse_liquid_$a)
      worst=$(awk -v h="$h" -v l="$l" -v w="$worst" 'BEGIN { s = h + l; if (s < 0) s = -s; m = (h < 0 ? -h : h) + 1e-300;
                 r = s / m; printf "%.3g", (r > w ? r : w) }')
    done
  done
  echo "largest |cloth + water| / |cloth| over 12 frames: $worst"
  awk -v w="$worst" 'BEGIN { exit !(w < 1e-9) }'
}
check "the coupled loop's momentum ledger balances every frame" ledger

# frames 1-6 on one thread, then resumed on two: the same bits as the uninterrupted bake on two threads (a difference
# between thread counts or a state the checkpoint misses would show)
"$BIN/bake" "$scene" -j 1 --frames 1-6 --out "$b3" -q >/dev/null 2>&1
"$BIN/bake" "$scene" -j 2 --out "$b3" --resume >"$WORK/resume.log" 2>&1
check "the bake resumes after frame 6" grep -q "resuming after frame 6" "$WORK/resume.log"
check "the coupled cloth begun on 1 thread and resumed on 2 is bit-identical to an uninterrupted bake on 2" \
  same_frames "$b2" "$b3" dip 12

"$BIN/mesh" "$scene" --out "$b2" -q >/dev/null 2>&1
obj="$b2/dip/mesh/towel.0012.obj"
check "mesh writes the towel as an OBJ with a normal per vertex and the mesh file's texture coordinates" bash -c "
  [ \$(grep -c '^v ' '$obj') -eq 1089 ] && [ \$(grep -c '^vn ' '$obj') -eq 1089 ] && [ \$(grep -c '^vt ' '$obj') -eq 6144 ] &&
  [ \$(grep -c '^f [0-9]*/[0-9]*/[0-9]* ' '$obj') -eq 2048 ]"
"$BIN/render" "$scene" --out "$b2" --frames 12-12 -q >/dev/null 2>&1
check "render draws the towel" test -s "$b2/dip/render/frame.0012.png"

# the flag in the wind: the air's stream carries the free edge downstream (+x)
flag=$(stage_scene cloth_flag.json)
python3 - "$flag" "$S/flag.json" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); s['shot']['name'] = 'flag'; s['shot']['frames'] = [1, 6]
w = s['elements'][0]['components']; w['AirDomain']['voxel_size'] = 0.1; w['Wind']['ramp'] = 0; w['Wind']['initial'] = 'stream'
s['elements'][1]['components']['ClothSolver'] = {'substeps': 8}
s['elements'][1]['components']['ClothMaterial']['self_contact'] = False
json.dump(s, open(sys.argv[2], 'w'))
s['shot']['name'] = 'calm'; w['Wind']['velocity'] = [0, 0, 0]
json.dump(s, open(sys.argv[2].replace('flag.json', 'calm.json'), 'w'))
PY
"$BIN/bake" "$S/flag.json" -j 2 --out "$b2" >"$WORK/flag.log" 2>&1; rc=$?
check "the flag in the wind bakes without a warning" bash -c "[ $rc -eq 0 ] && ! grep -qi warn '$WORK/flag.log'"
"$BIN/bake" "$S/calm.json" -j 2 --out "$b2" -q >/dev/null 2>&1
blown() {
  local xw xc
  xw=$(h5 "$b2/flag/bake/frame.0006.h5" /flag/position | tr ' ' '\n' | awk 'NF { k++; if (k % 3 == 1) { s += $1; n++ } } END { print s / n }')
  xc=$(h5 "$b2/calm/bake/frame.0006.h5" /flag/position | tr ' ' '\n' | awk 'NF { k++; if (k % 3 == 1) { s += $1; n++ } } END { print s / n }')
  echo "the flag's mean x at frame 6: in the wind $xw m, in still air $xc m"
  awk -v a="$xc" -v b="$xw" 'BEGIN { exit !(b > a + 0.002) }'
}
check "the wind carries the flag downstream of where it hangs in still air" blown

# a curtain: the panel's edge z = -0.5 slides on a rail along x (SlideVertices), the panel swinging down from it
python3 - "$ROOT" "$S" <<'PY'
import json, sys
root, d = sys.argv[1], sys.argv[2]
s = {"shot": {"name": "curtain", "fps": 24, "frames": [1, 6]},
     "elements": [{"name": "curtain", "type": "cloth", "components": {
         "Mesh": {"file": root + "/assets/meshes/cloth_panel.obj"}, "Transform": {"translate": [0, 1, 0]},
         "ClothMaterial": {"self_contact": False}, "ClothSolver": {"substeps": 8},
         "SlideVertices": {"box": [[-1, 0.9, -0.51], [1, 1.1, -0.49]], "curve": [[-2, 1, -0.5], [2, 1, -0.5]]}}}]}
json.dump(s, open(d + "/curtain.json", "w"))
s["shot"]["name"] = "rail1"; s["elements"][0]["components"]["SlideVertices"]["curve"] = [[0, 1, -0.5]]
json.dump(s, open(d + "/rail1.json", "w"))
PY
"$BIN/bake" "$S/curtain.json" -j 2 --out "$b2" >"$WORK/curtain.log" 2>&1; rc=$?
on_rail() {
  h5 "$b2/curtain/bake/frame.0006.h5" /curtain/position | tr ' ' '\n' | awk 'NF' | paste - - - |
    awk '$3 < -0.49 { n++; d = sqrt(($2 - 1) ^ 2 + ($3 + 0.5) ^ 2); if (d > w) w = d } $2 < low || NR == 1 { low = $2 }
         END { printf "%d vertices on the rail, at most %.3g m off it; the lowest vertex at %.3f m\n", n, w, low
               exit !(n == 33 && w < 1e-6 && low < 0.7) }'
}
check "the curtain bakes without a warning" bash -c "[ $rc -eq 0 ] && ! grep -qi warn '$WORK/curtain.log'"
check "a SlideVertices edge stays on its rail (within 1e-6 m) while the curtain swings down" on_rail

# a sheet dropped onto a bem_solid icosphere (radius 0.1 m, its lower half held by FixedVertices, the same body as
# test_hair_bodies.sh's) rests on its deformed surface: after 1.5 s no vertex is nearer its faces' planes than 0.8 of the
# 1 mm contact distance (the contact keeps the Euclidean distance to the surface, which beside an edge or a corner of
# this 42-vertex body exceeds the distance to the nearest face's plane: cos 21° = 0.93 of it across an edge, less at a
# corner), the sheet touches the body over many vertices, and those have come to rest (the hanging rim still swings)
python3 - "$ROOT" "$S" <<'PY'
import json, sys
root, d = sys.argv[1], sys.argv[2]
n = 17
lines = []
for j in range(n):
    for i in range(n):
        lines.append("v %.6f 0 %.6f" % (0.3 * i / (n - 1) - 0.15, 0.3 * j / (n - 1) - 0.15))
idx = lambda i, j: i + n * j + 1
for j in range(n - 1):
    for i in range(n - 1):
        a, b, c, e = idx(i, j), idx(i + 1, j), idx(i, j + 1), idx(i + 1, j + 1)
        lines += ["f %d %d %d" % (a, c, e), "f %d %d %d" % (a, e, b)]
open(d + "/sheet17.obj", "w").write("\n".join(lines) + "\n")
s = json.load(open(root + "/tests/data/hair_drape_bem.json"))
s["shot"]["name"] = "drape_bem"; s["shot"]["frames"] = [1, 36]
s["elements"][0]["components"]["Mesh"]["file"] = root + "/tests/data/bem_ico1.obj"
s["elements"][1] = {"name": "sheet", "type": "cloth", "components": {
    "Mesh": {"file": d + "/sheet17.obj"}, "Transform": {"translate": [0.01, 0.215, 0.02]},
    "ClothMaterial": {"damping": 0.02}, "Collider": {"friction": 0.5, "thickness": 0.001}}}
json.dump(s, open(d + "/drape_bem.json", "w"))
PY
"$BIN/precompute" "$S/drape_bem.json" -j 2 >/dev/null 2>&1
"$BIN/bake" "$S/drape_bem.json" -j 2 --out "$b2" >"$WORK/drape.log" 2>&1; rc=$?
[ "$rc" -eq 0 ] || tail -5 "$WORK/drape.log"
check "a sheet over a bem_solid bakes without a warning" bash -c "[ $rc -eq 0 ] && ! grep -qi warn '$WORK/drape.log'"
on_bem() {
  local g n v
  read -r g n v <<<"$(bem_gaps "$b2/drape_bem/bake/frame.0036.h5" rock sheet 0.001)"
  echo "closest vertex $g m from the body (contact at 1e-3 m), $n vertices within 2 mm, the fastest of them $v m/s"
  awk -v g="$g" -v n="$n" -v v="$v" 'BEGIN { exit !(g >= 0.8e-3 && n >= 10 && v < 0.01) }'
}
check "the sheet rests on the bem_solid's deformed surface, within 20 % of its contact thickness" on_bem

# a sheet dropped onto an elastic mpm_solid block (0.16 x 0.1 x 0.16 m on the floor, tests/data/hair_drape_mpm.json's)
# rests on the surface its particles make (contact.h's point field, within about a tenth of a particle radius, 1 mm,
# of the block's top at 0.1 m): after 1 s the vertices over the block lie at 0.1 m + the 1 mm contact distance, none
# deeper than 5 mm into it, and have come to rest
python3 - "$ROOT" "$S" <<'PY'
import json, sys
root, d = sys.argv[1], sys.argv[2]
s = json.load(open(root + "/tests/data/hair_drape_mpm.json"))
s["shot"]["name"] = "drape_mpm"; s["shot"]["frames"] = [1, 24]
s["elements"][1] = {"name": "sheet", "type": "cloth", "components": {
    "Mesh": {"file": d + "/sheet17.obj"}, "Transform": {"translate": [0.0, 0.13, 0.0]},
    "ClothMaterial": {"damping": 0.02}, "Collider": {"friction": 0.5, "thickness": 0.001}}}
json.dump(s, open(d + "/drape_mpm.json", "w"))
PY
"$BIN/bake" "$S/drape_mpm.json" -j 2 --out "$b2" >"$WORK/drape_mpm.log" 2>&1; rc=$?
[ "$rc" -eq 0 ] || tail -5 "$WORK/drape_mpm.log"
check "a sheet over an mpm_solid bakes without a warning" bash -c "[ $rc -eq 0 ] && ! grep -qi warn '$WORK/drape_mpm.log'"
on_mpm() {
  local f="$b2/drape_mpm/bake/frame.0024.h5"
  paste <(h5 "$f" /sheet/position | tr ' ' '\n' | awk 'NF' | paste - - -) \
        <(h5 "$f" /sheet/velocity | tr ' ' '\n' | awk 'NF' | paste - - -) |
    awk '$1 > -0.07 && $1 < 0.07 && $3 > -0.07 && $3 < 0.07 {
           n++; if (n == 1 || $2 < lo) lo = $2; if ($2 > hi) hi = $2; s = sqrt($4 * $4 + $5 * $5 + $6 * $6); if (s > v) v = s }
         END { printf "%d vertices over the block between %.5f and %.5f m, the fastest at %.3g m/s\n", n, lo, hi, v
               exit !(n >= 25 && lo > 0.095 && hi < 0.11 && v < 0.02) }'
}
check "the sheet rests on the mpm_solid's surface" on_mpm

# bad input: a mesh that is not a manifold, a pin box holding nothing, a value out of range
python3 - "$scene" "$S" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); d = sys.argv[2]
open(d + '/../meshes/fin.obj', 'w').write("v 0 0 0\nv 1 0 0\nv 0 0 1\nv 0 1 0\nv 0 -1 0\nf 1 2 3\nf 2 1 4\nf 1 2 5\n")
a = json.loads(json.dumps(s)); a['shot']['name'] = 'fin'; a['elements'][1]['components']['Mesh']['file'] = '../meshes/fin.obj'
a['elements'][1]['components'].pop('FixedVertices'); a['elements'][1]['components'].pop('Motion')
json.dump(a, open(d + '/fin.json', 'w'))
b = json.loads(json.dumps(s)); b['shot']['name'] = 'nopin'; b['elements'][1]['components']['FixedVertices']['box'] = [[5, 5, 5], [6, 6, 6]]
json.dump(b, open(d + '/nopin.json', 'w'))
c = json.loads(json.dumps(s)); c['shot']['name'] = 'nu'; c['elements'][1]['components']['ClothMaterial']['poisson'] = 0.6
json.dump(c, open(d + '/nu.json', 'w'))
e = json.loads(json.dumps(s)); e['shot']['name'] = 'two'
second = json.loads(json.dumps(e['elements'][1])); second['name'] = 'rag'; second['components']['ClothSolver'] = {'substeps': 4}
second['components'].pop('ClothDrag'); e['elements'].append(second)
json.dump(e, open(d + '/two.json', 'w'))
PY
expect_exit "a non-manifold cloth mesh exits 2 naming the element, the field and the edge" 2 \
  "towel\.Mesh\.file.*edge \(0, 1\) borders 3 triangles" "$BIN/bake" "$S/fin.json" --frames 1-1
check "and writes no frame" bash -c "[ ! -e '$DRENCH_OUT/fin/bake/frame.0001.h5' ]"
expect_exit "a FixedVertices box holding no vertex exits 2 with the fix" 2 "towel.*FixedVertices\.box holds none.*enlarge the box" \
  "$BIN/bake" "$S/nopin.json" --frames 1-1
expect_exit "a Poisson ratio out of range exits 2 naming the field and the range" 2 "towel\.ClothMaterial\.poisson" \
  "$BIN/bake" "$S/nu.json" --frames 1-1
expect_exit "a slide curve of one point exits 2 naming the field and the fix" 2 \
  "curtain\.SlideVertices\.curve has 1 point.*2 points or more" "$BIN/bake" "$S/rail1.json" --frames 1-1
expect_exit "two cloth elements stepped differently exit 2 naming both and the fix" 2 \
  "rag\.ClothSolver\.substeps = 4 differs from towel\.ClothSolver\.substeps = 8.*give both elements the same" \
  "$BIN/bake" "$S/two.json" --frames 1-1
