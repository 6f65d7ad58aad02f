#!/usr/bin/env bash
# A bem_solid body two-way with the liquid (BemSolver.liquid_coupling "two_way", the default): tests/data/bem_dam.json
# breaks a 0.25 × 0.3 m dam of water on a soft jelly (μ = 20 kPa, 1100 kg/m³, the 42-vertex icosphere of radius 0.1 m)
# resting on a floor collider. The wave pushes the jelly downstream and squeezes it (its largest displacement rises,
# then rings down), the jelly deflects the flow (the liquid differs from the same bake with the jelly one-way, which
# the wave cannot move), no particle gets into the jelly's deformed surface, the frames carry the liquid's impulse
# on the body, and the bake is bit-identical on 1 and 2 threads and when resumed.
source "$(dirname "$0")/lib.sh"
scene="$ROOT/tests/data/bem_dam.json"
S="$WORK/scenes"; mkdir -p "$S"
sed 's#"history_margin": 8 }#"history_margin": 8, "liquid_coupling": "one_way" }#; s#bem_ico1.obj#'"$ROOT"'/tests/data/bem_ico1.obj#; s#\.\./\.\./assets#'"$ROOT"'/assets#' "$scene" > "$S/one_way.json"
fr() { printf "%s/bem_dam/bake/frame.%04d.h5" "$1" "$2"; }

out=$("$BIN/precompute" "$scene" -j 2 2>&1); rc=$?
check "precompute builds the jelly's matrices" bash -c "[ $rc -eq 0 ]"
b1="$WORK/b1"; b2="$WORK/b2"; b3="$WORK/b3"; b4="$WORK/b4"
t=$EPOCHREALTIME
out=$("$BIN/bake" "$scene" -j 2 --out "$b2" 2>&1); rc=$?
awk -v a="$t" -v b="$EPOCHREALTIME" 'BEGIN{printf "bake of 14 frames took %.1fs\n", b-a}'
[ "$rc" -eq 0 ] || echo "$out" | tail -5
baked() { [ "$rc" -eq 0 ] && [ "$(ls "$b2"/bem_dam/bake/frame.*.h5 2>/dev/null | wc -l)" -eq 14 ]; }
check "bake exits 0 and writes 14 frame caches" baked

pushed() { # the jelly starts at x = 0.5 m; the wave carries it more than 0.1 m downstream by frame 14
  awk -v T="$(h5 "$(fr "$b2" 14)" /jelly/translation)" 'BEGIN { split(T, t, " "); printf "frame 14: jelly at x = %.4f m\n", t[1]; exit !(t[1] > 0.6) }'
}
check "the wave pushes the jelly downstream" pushed
rings() { # max |u|: its least before the wave arrives (frames 3-5), its peak as the wave squeezes it, and after
  local f u s=""
  for f in $(seq 3 14); do u=$(h5 "$(fr "$b2" "$f")" /diagnostics/bem_max_displacement); s="$s $u"; done
  echo "max |u| per frame 3-14 (m):$s"
  awk -v s="$s" 'BEGIN { n = split(s, u, " "); lo = u[1]; for (i = 1; i <= 3; i++) if (u[i] < lo) lo = u[i]
    peak = 0; at = 0; for (i = 1; i <= n; i++) if (u[i] > peak) { peak = u[i]; at = i }
    after = peak; for (i = at + 1; i <= n; i++) if (u[i] < after) after = u[i]
    printf "before the wave %.4g m, peak %.4g m (frame %d), least after it %.4g m\n", lo, peak, at + 2, after
    exit !(peak > 1.5 * lo && after < 0.5 * peak) }'
}
check "the wave deforms the jelly and the deformation rings down" rings
ledger() { # the impulse the liquid gave the body is in every frame's diagnostics, and non-zero once the wave hits
  local j; j=$(h5 "$(fr "$b2" 8)" /diagnostics/bem_liquid_impulse)
  echo "frame 8: liquid impulse on the bodies ($j) N s"
  awk -v J="$j" 'BEGIN { split(J, v, " "); exit !(v[1] > 0.01) }'
}
check "frames carry the liquid's impulse on the bodies" ledger

# the one-way jelly stays put and the liquid flows differently around it
"$BIN/precompute" "$S/one_way.json" -j 2 >/dev/null 2>&1
"$BIN/bake" "$S/one_way.json" -j 2 --out "$b4" -q >/dev/null 2>&1
mean_x() { h5 "$1" /water/position | awk '{ s = 0; for (i = 1; i <= NF; i += 3) s += $i; printf "%.6f", s / (NF / 3) }'; }
deflects() {
  local a b T
  T=$(h5 "$(fr "$b4" 14)" /jelly/translation); a=$(mean_x "$(fr "$b2" 14)"); b=$(mean_x "$(fr "$b4" 14)")
  echo "frame 14: one-way jelly at ($T); the water's mean x $a m two-way, $b m one-way"
  awk -v a="$a" -v b="$b" -v T="$T" 'BEGIN { split(T, t, " "); d = a - b; if (d < 0) d = -d; exit !(d > 0.003 && t[1] < 0.501) }'
}
check "the jelly deflects the flow (the water differs from the one-way bake's)" deflects

# two bodies stepped together (one time_step) must share one liquid_coupling: exit 2 naming both fields, no frame
python3 - "$scene" "$S/mixed.json" "$ROOT" <<'PY'
import json, sys
sc = json.load(open(sys.argv[1]))
root = sys.argv[3]
for e in sc["elements"]:
    if e["name"] == "floor": e["components"]["Mesh"]["file"] = root + "/assets/meshes/ground.obj"
    if e["name"] == "jelly": e["components"]["Mesh"]["file"] = root + "/tests/data/bem_ico1.obj"
j = json.loads(json.dumps([e for e in sc["elements"] if e["name"] == "jelly"][0]))
j["name"] = "jelly2"; j["components"]["Transform"]["translate"] = [0.7, 0.102, 0.15]
j["components"]["BemSolver"]["liquid_coupling"] = "one_way"
sc["elements"].append(j); sc["shot"]["name"] = "mixed"
json.dump(sc, open(sys.argv[2], "w"))
PY
"$BIN/precompute" "$S/mixed.json" -j 2 >/dev/null 2>&1
expect_exit "bodies stepped together with different liquid_coupling" 2 \
  "jelly2\.BemSolver\.liquid_coupling = \"one_way\" but jelly\.BemSolver\.liquid_coupling = \"two_way\"" \
  "$BIN/bake" "$S/mixed.json" --out "$WORK/mixed"
check "and writes no frame" bash -c "! ls '$WORK'/mixed/mixed/bake/frame.*.h5 >/dev/null 2>&1"

# no particle more than half a cell inside the jelly's deformed surface (planes of its posed triangles: the icosphere
# stays convex under these displacements)
deepest() {
  local f; f=$(fr "$b2" "$1")
  h5 "$f" /water/position |
  awk -v R="$(h5 "$f" /jelly/rotation)" -v T="$(h5 "$f" /jelly/translation)" -v X="$(h5 "$f" /jelly/reference)" \
      -v U="$(h5 "$f" /jelly/displacement)" -v K="$(h5 "$f" /jelly/triangles)" "$AWK_SURFACE"'BEGIN {
    split(R, r, " "); split(T, t, " "); n = split(X, x, " "); split(U, u, " "); for (i = 1; i <= n; i++) x[i] += u[i]
    nt = split(K, k, " ") / 3; face_planes(x, k, nt) }
  { np = split($0, p, " ") / 3; worst = -1
    for (j = 0; j < np; j++) {
      to_body(p, j, r, t, q); m = 1
      for (i = 0; i < nt && m > -0.02; i++) { s = O[i] - (N[i, 1] * q[1] + N[i, 2] * q[2] + N[i, 3] * q[3]); if (s < m) m = s }
      if (m > worst) worst = m }
    printf "%.6f", worst }'
}
inside_ok() {
  local f d worst=-1
  for f in 5 8 11 14; do d=$(deepest "$f"); worst=$(awk -v a="$worst" -v b="$d" 'BEGIN { print (b > a ? b : a) }'); done
  echo "frames 5, 8, 11, 14: the deepest particle is $worst m inside the deformed jelly"
  awk -v w="$worst" 'BEGIN { exit !(w < 0.01) }'
}
check "no liquid particle more than half a cell (0.01 m) inside the deformed jelly" inside_ok

"$BIN/bake" "$scene" -j 1 --out "$b1" -q >/dev/null 2>&1
check "the two-way bake is bit-identical on 1 and 2 threads" same_frames "$b1" "$b2" bem_dam 14
"$BIN/bake" "$scene" -j 2 --frames 1-7 --out "$b3" -q >/dev/null 2>&1
"$BIN/bake" "$scene" -j 2 --out "$b3" --resume >"$WORK/resume.log" 2>&1
check "the bake resumes after frame 7" grep -q "resuming after frame 7" "$WORK/resume.log"
check "a resumed two-way bake is bit-identical to an uninterrupted one" same_frames "$b2" "$b3" bem_dam 14
