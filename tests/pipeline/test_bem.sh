# BEM precompute: a bem_solid body's matrices are built once into cache/bem/<key>.h5, a file that describes
# itself; a second run is a cache hit; the key follows exactly what enters the matrices; bodies with one key are
# built once; a killed build leaves nothing trusted; bad meshes exit 2 naming the element, the file and the
# problem and write nothing; bake reads the matrices and runs the body.
source "$(dirname "$0")/lib.sh"
S="$WORK/scenes"; mkdir -p "$S"
cp "$ROOT/tests/data/bem_ico1.obj" "$S/"
base="$ROOT/tests/data/bem_small.json"
bem="$DRENCH_CACHE/bem"

# mk NAME SED: a copy of the small scene with its shot named NAME, edited by SED
mk() { sed "s#\"name\": \"bem_small\"#\"name\": \"$1\"#; $2" "$base" > "$S/$1.json"; echo "$S/$1.json"; }
h5files() { find "$1" -maxdepth 1 -name '*.h5' 2>/dev/null | wc -l; }
# attr FILE NAME: the value of a root attribute (strings without quotes)
attr() { h5dump -a "/$2" "$1" 2>/dev/null | awk '/\(0\):/{sub(/.*\(0\): */, ""); sub(/^"/, ""); sub(/"$/, ""); print; exit}'; }
mtime() { stat -c %y "$1"; }
pre() { "$BIN/precompute" "$@" -j 2 2>&1; }

# 1. the first run builds and writes one file
t=$EPOCHREALTIME
out=$(pre "$(mk bem_a '')"); rc=$?
awk -v a="$t" -v b="$EPOCHREALTIME" 'BEGIN{printf "precompute of a 42-vertex body took %.1fs\n", b-a}'
[ "$rc" -eq 0 ] || echo "$out" | tail -5
check "precompute on a bem_solid scene exits 0" test "$rc" -eq 0
check "it writes exactly one cache/bem/<key>.h5" test "$(h5files "$bem")" -eq 1
f=$(find "$bem" -maxdepth 1 -name '*.h5' 2>/dev/null | head -1); f=${f:-$bem/none.h5}; key=$(basename "$f" .h5)
check "the file is named by a 32-hex-digit key" grep -Eq '^[0-9a-f]{32}$' <<<"$key"
check "nothing else is left in cache/bem" test "$(ls -A "$bem" 2>/dev/null | wc -l)" -eq 1
check "the summary line counts the body as computed" grep -Eq '^precompute: 1 bem body, 0 hits, 1 computed, [0-9.]+ s, peak RSS [0-9.]+ [KMG]iB$' <<<"$out"
check "the weld is logged" grep -q "bem: jelly: .*bem_ico1.obj: 42 vertices, 80 triangles (0 of 42 vertices merged" <<<"$out"
check "the MANIFEST lists the body and its key" grep -q "^input bem jelly $key$" "$DRENCH_OUT/bem_a/precompute/MANIFEST"
sizes_ok() {
  [ "$(h5dump -A "$f" | grep -c ATTRIBUTE)" -ge 25 ] && [ "$(attr "$f" kind)" = bem ] && [ "$(attr "$f" key)" = "$key" ] &&
  [ "$(attr "$f" n_vertices)" = 42 ] && [ "$(attr "$f" n_triangles)" = 80 ] && [ "$(attr "$f" n)" = 126 ] &&
  [ "$(attr "$f" n_max)" = 4 ]
}
# n_max = ⌊r_max/(c₂Δt) + 2⌋ with r_max = 0.2 m (the diameter), c₂ = √(μ/ρ) = 10 m/s, Δt = 0.01 s: 4
check "h5dump -A: kind, key, sizes and history length" sizes_ok
material_ok() {
  [ "$(attr "$f" dt)" = 0.01 ] && [ "$(attr "$f" density)" = 1000 ] && [ "$(attr "$f" shear_modulus)" = 100000 ] &&
  [ "$(attr "$f" poisson)" = 0.4 ] && [ "$(attr "$f" shear_wave_speed)" = 10 ] &&
  awk -v c="$(attr "$f" longitudinal_wave_speed)" 'BEGIN{exit !(c > 24.49 && c < 24.50)}' && # c₁ = c₂√(2(1−ν)/(1−2ν))
  [ "$(attr "$f" compression_ratio)" = 4 ] && [ "$(attr "$f" ordering)" = vertex_xyz ] &&
  [ "$(attr "$f" bem_version)" = bem-2 ]
}
check "h5dump -A: material, time step, wave speeds, compression" material_ok
inputs_ok() {
  local inputs hash; inputs=$(attr "$f" inputs); hash=$(attr "$f" asset_hash)
  grep -Eq '^[0-9a-f]{32}$' <<<"$hash" && grep -q '"shear_modulus":100000,' <<<"$inputs" &&
  grep -q "\"mesh_hash\":\"$hash\"" <<<"$inputs"
}
check "h5dump -A: the inputs and the asset's hash" inputs_ok
units_ok() {
  h5dump -a /mesh/x/units "$f" | grep -q '"m"' && h5dump -a /G/0/val/units "$f" | grep -q 'm/Pa' &&
  h5dump -a /D/units "$f" | grep -q 's^2' && h5dump -a /H0inv_Gp/val/units "$f" | grep -q 'm/Pa'
}
check "datasets carry units" units_ok
shapes_ok() {
  h5dump -H -d /mesh/x "$f" | grep -q '( 42, 3 )' && h5dump -H -d /D "$f" | grep -q '( 5, 126, 3 )' &&
  h5dump -H -g /H/4 "$f" >/dev/null 2>&1 && ! h5dump -H -g /H/5 "$f" >/dev/null 2>&1
}
check "shapes: x N×3, D (n_max+1)×3N×3, H_0..H_4 and no H_5" shapes_ok

# 2. a second run is a no-op: a cache hit, the file untouched
m0=$(mtime "$f")
out=$(pre "$S/bem_a.json"); rc=$?
check "a second precompute exits 0" test "$rc" -eq 0
check "a second precompute is a cache hit" grep -q "bem: jelly: cache hit $key" <<<"$out"
check "and counts it so" grep -Eq '^precompute: 1 bem body, 1 hit, 0 computed' <<<"$out"
check "the file is not rewritten" test "$(mtime "$f")" = "$m0"

# 3. what enters the matrices makes a new key; what does not, does not
pre "$(mk bem_dt 's#"time_step": 0.01#"time_step": 0.02#')" >/dev/null
check "another time_step writes a second key file" test "$(h5files "$bem")" -eq 2
pre "$(mk bem_mu 's#"shear_modulus": 1e5#"shear_modulus": 2e5#')" >/dev/null
check "another shear_modulus writes a third key file" test "$(h5files "$bem")" -eq 3
out=$(pre "$(mk bem_renamed 's#"name": "jelly"#"name": "wobble"#')")
check "renaming the element recomputes nothing" grep -q "bem: wobble: cache hit $key" <<<"$out"
collider='s#"elements": \[#"elements": [ { "name": "floor", "type": "collider", "components": { "Mesh": { "file": "bem_ico1.obj" } } },#'
out=$(pre "$(mk bem_collider "$collider")")
check "adding another element recomputes nothing" bash -c "grep -q 'cache hit $key' <<<'$out' && grep -q ', 0 computed' <<<'$out'"
check "no key file was added by either" test "$(h5files "$bem")" -eq 3
check "the first file was never rewritten" test "$(mtime "$f")" = "$m0"

# 4. two bodies of one mesh and material are built once (a fresh cache)
twin='s#"elements": \[#"elements": [ { "name": "twin", "type": "bem_solid", "components": { "Mesh": { "file": "bem_ico1.obj" }, "Compression": { "ratio": 4.0 }, "BemSolver": { "time_step": 1e-2 } } },#'
out=$(DRENCH_CACHE="$WORK/cache_twin" pre "$(mk bem_twin "$twin")")
check "two bodies with one key are computed once" grep -Eq '^precompute: 2 bem bodies, 0 hits, 1 computed' <<<"$out"
check "the second is said to share the first's matrices" grep -q "bem: jelly: same matrices as twin ($key)" <<<"$out"
check "one file, under the key of the single body" bash -c "[ $(h5files "$WORK/cache_twin/bem") -eq 1 ] && [ -e '$WORK/cache_twin/bem/$key.h5' ]"

# 5. a build killed with SIGKILL leaves nothing a later run trusts, and the stage stale; the next run computes it
# a level-2 icosphere of radius 0.1 m (162 vertices): each triangle of the level-1 one split
# in four at its edge midpoints, pushed out to the sphere
awk '/^v /{n++; x[n]=$2; y[n]=$3; z[n]=$4} /^f /{m++; a[m]=$2; b[m]=$3; c[m]=$4}
  function mid(i, j,   k, px, py, pz, l) {
    k = i < j ? i " " j : j " " i; if (k in M) return M[k]
    px = (x[i] + x[j]) / 2; py = (y[i] + y[j]) / 2; pz = (z[i] + z[j]) / 2; l = sqrt(px * px + py * py + pz * pz) / 0.1
    n++; x[n] = px / l; y[n] = py / l; z[n] = pz / l; M[k] = n; return n }
  END { for (t = 1; t <= m; t++) { p = mid(a[t], b[t]); q = mid(b[t], c[t]); r = mid(c[t], a[t])
          F[++o] = a[t] " " p " " r; F[++o] = b[t] " " q " " p; F[++o] = c[t] " " r " " q; F[++o] = p " " q " " r }
        for (i = 1; i <= n; i++) printf "v %.12g %.12g %.12g\n", x[i], y[i], z[i]
        for (t = 1; t <= o; t++) print "f " F[t] }' "$S/bem_ico1.obj" > "$S/big.obj"
check "the generated level-2 icosphere has 162 vertices and 320 triangles" \
  bash -c "[ \$(grep -c '^v ' '$S/big.obj') -eq 162 ] && [ \$(grep -c '^f ' '$S/big.obj') -eq 320 ]"
kc="$WORK/cache_kill"
small=$(mk bem_big '')
DRENCH_CACHE="$kc" pre "$small" >/dev/null # the shot's precompute MANIFEST exists before the killed run
# with two quadrature levels: a build of several seconds to kill
big=$(mk bem_big 's#bem_ico1.obj#big.obj#; s#"time_step": 0.01#"time_step": 0.01, "quadrature_levels": 2#')
DRENCH_CACHE="$kc" "$BIN/precompute" "$big" -j 2 >"$WORK/kill.log" 2>&1 &
pid=$!
# killed once the build reports its first collocation vertex done
for _ in $(seq 1 600); do grep -q '^bem jelly: .* 1/162' "$WORK/kill.log" && break; kill -0 $pid 2>/dev/null || break; sleep 0.05; done
if kill -0 $pid 2>/dev/null; then
  kill -9 $pid; wait $pid 2>/dev/null
  check "a killed build leaves no new <key>.h5" test "$(h5files "$kc/bem")" -eq 1
  check "a killed build leaves the stage stale (no MANIFEST)" test ! -e "$DRENCH_OUT/bem_big/precompute/MANIFEST"
  out=$(DRENCH_CACHE="$kc" pre "$big"); rc=$?
  check "the next run computes it" bash -c "[ $rc -eq 0 ] && grep -Eq '^precompute: 1 bem body, 0 hits, 1 computed' <<<'$out'"
  check "and leaves only finished files" bash -c "[ $(h5files "$kc/bem") -eq 2 ] && [ \$(ls -A '$kc/bem' | wc -l) -eq 2 ]"
else
  wait $pid
  fail "a killed build leaves no new <key>.h5" "the build finished before it could be killed; use a larger mesh: $(tail -2 "$WORK/kill.log")"
fi

# 6. bad meshes: exit 2 naming the element, the file and the problem; nothing written
bc="$WORK/cache_bad"
for m in "open:an open:open|boundary" "nonmanifold:a non-manifold:manifold" "inward:an inward-facing:inward|orient"; do
  name=${m%%:*}; rest=${m#*:}; label="${rest%%:*} mesh"; problem=${rest#*:}
  cp "$ROOT/tests/data/bad/bem_$name.obj" "$S/"
  sc=$(mk "bad_$name" "s#bem_ico1.obj#bem_$name.obj#; s#\"name\": \"jelly\"#\"name\": \"blob_$name\"#")
  out=$(DRENCH_CACHE="$bc" "$BIN/precompute" "$sc" 2>&1); rc=$?
  if [ $rc -ne 2 ]; then fail "$label exits 2" "exit $rc: $(head -3 <<<"$out")"
  elif ! grep -q "blob_$name\.Mesh\.file" <<<"$out"; then fail "$label names the element" "$(head -3 <<<"$out")"
  elif ! grep -q "bem_$name\.obj" <<<"$out"; then fail "$label names the file" "$(head -3 <<<"$out")"
  elif ! grep -Eiq "$problem" <<<"$out"; then fail "$label names the problem" "no /$problem/ in: $(head -3 <<<"$out")"
  else pass "$label exits 2 naming the element, the file and the problem"; fi
  check "$label writes nothing" bash -c "[ ! -e '$bc/bem' ] && [ ! -e '$DRENCH_OUT/bad_$name' ]"
done

# 7. bake moves the body on the matrices precompute left in the cache (test_bem_shot.sh checks the motion)
out=$("$BIN/bake" "$S/bem_a.json" -j 2 2>&1); rc=$?
[ "$rc" -eq 0 ] || echo "$out" | tail -5
check "bake runs on a bem_solid scene" bash -c "[ $rc -eq 0 ] && [ \$(ls '$DRENCH_OUT/bem_a/bake'/frame.*.h5 | wc -l) -eq 2 ]"
check "it reads the body's matrices from the cache: 4 steps of 0.01 s per 25 fps frame" \
  grep -q "bem: jelly: 42 vertices, matrices $key (n_max 4), 4 steps of 0.01 s per frame" <<<"$out"
