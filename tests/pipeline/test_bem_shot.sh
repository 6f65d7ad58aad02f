# BEM bodies in a shot: a 42-vertex icosphere, placed by its Transform, is dropped from rest with a moving frame
# (3 frames at 24 fps, 10 steps of 1/240 s each). precompute then bake: the frame cache holds the body as DESIGN §4
# says; the frame falls exactly as its integrator says; the displacement stays tiny; mesh writes the surface the
# frame cache describes; render draws it; InitialVelocity launches and spins it; frame_update and
# error_correction do not touch the matrices' key; a time step that does not divide the frame, a scale and a
# missing precompute exit 2 and write nothing; pipeline.sh runs all four stages. (Resume: test_determinism.sh.)
source "$(dirname "$0")/lib.sh"
S="$WORK/scenes"; mkdir -p "$S"
# The icosphere moved by (0.03, 0, -0.02), so its centre of mass x̄ is off the file's origin: the frame starts at
# T₀ = R₀x̄ + translate, not at translate.
awk '/^v /{printf "v %.12g %.12g %.12g\n", $2 + 0.03, $3, $4 - 0.02; next} {print}' "$ROOT/tests/data/bem_ico1.obj" \
  > "$S/ico_off.obj"
base="$S/bem_drop.json"
sed 's#bem_ico1.obj#ico_off.obj#' "$ROOT/tests/data/bem_drop.json" > "$base"
# mk NAME SED: a copy of the drop scene with its shot named NAME, edited by SED
mk() { sed "s#\"name\": \"bem_drop\"#\"name\": \"$1\"#; $2" "$base" > "$S/$1.json"; echo "$S/$1.json"; }
bd="$DRENCH_OUT/bem_drop/bake"; md="$DRENCH_OUT/bem_drop/mesh"; rd="$DRENCH_OUT/bem_drop/render"
# h5 FILE DATASET: its numbers in full precision, one line
h5() { h5dump -y -w 0 -A 0 -m '%.17g' -d "$2" "$1" 2>/dev/null | awk '/DATA \{/{on=1; next} on && /^ *\}/{on=0} on { gsub(/,/, " "); printf "%s ", $0 } END { print "" }'; }
attr() { h5dump -a "$2" "$1" 2>/dev/null | awk '/\(0\):/{sub(/.*\(0\): */, ""); gsub(/"/, ""); print; exit}'; }

# 1. precompute, then bake
out=$("$BIN/precompute" "$base" -j 2 2>&1); rc=$?
check "precompute builds the body's matrices" bash -c "[ $rc -eq 0 ] && grep -Eq '^precompute: 1 bem body, 0 hits, 1 computed' <<<'$out'"
t=$EPOCHREALTIME
out=$("$BIN/bake" "$base" -j 2 2>&1); rc=$?
awk -v a="$t" -v b="$EPOCHREALTIME" 'BEGIN{printf "bake of 3 frames (30 BEM steps) took %.1fs\n", b-a}'
[ "$rc" -eq 0 ] || echo "$out" | tail -5
check "bake exits 0 and writes 3 frame caches" bash -c "[ $rc -eq 0 ] && [ \$(ls '$bd'/frame.*.h5 2>/dev/null | wc -l) -eq 3 ]"
check "a scene of one bem_solid builds no grid, no MPM solver, no rod solver" \
  grep -q "world: 0 liquid grid(s), no MPM solver, no hair, 1 BEM body with 42 vertices (1 matrix set), 0 collider SDF(s)" <<<"$out"
check "each frame takes 1/24 s / (1/240 s) = 10 steps" grep -q "bem: jelly: 42 vertices, matrices [0-9a-f]\{32\} (n_max [0-9]*), 10 steps of 0.00416667 s per frame" <<<"$out"

# 2. the frame cache
f1="$bd/frame.0001.h5"
shapes_ok() {
  h5dump -H -d /jelly/rotation "$f1" | grep -q '( 3, 3 )' && h5dump -H -d /jelly/translation "$f1" | grep -q '( 3 )' &&
  h5dump -H -d /jelly/velocity "$f1" | grep -q '( 3 )' && h5dump -H -d /jelly/angular_velocity "$f1" | grep -q '( 3 )' &&
  h5dump -H -d /jelly/displacement "$f1" | grep -q '( 42, 3 )' && h5dump -H -d /jelly/reference "$f1" | grep -q '( 42, 3 )' &&
  h5dump -H -d /jelly/triangles "$f1" | grep -q '( 80, 3 )' && h5dump -H -d /jelly/triangles "$f1" | grep -q 'H5T_STD_I32LE'
}
check "rotation 3×3, translation 3, velocity 3, angular_velocity 3, displacement and reference 42×3, triangles 80×3 int" shapes_ok
units_ok() {
  [ "$(attr "$f1" /jelly/rotation/units)" = 1 ] && [ "$(attr "$f1" /jelly/translation/units)" = m ] &&
  [ "$(attr "$f1" /jelly/velocity/units)" = m/s ] && [ "$(attr "$f1" /jelly/angular_velocity/units)" = rad/s ] &&
  [ "$(attr "$f1" /jelly/displacement/units)" = m ] && [ "$(attr "$f1" /jelly/reference/units)" = m ] &&
  [ "$(attr "$f1" /jelly/triangles/units)" = 1 ] && [ "$(attr "$f1" /jelly/type)" = bem_solid ] &&
  [ "$(attr "$f1" /jelly/time_step)" = 0.00416667 ] # h5dump prints attributes to 6 digits
}
check "datasets carry units; the group its type and time step" units_ok
diag_ok() {
  local d
  for d in linear_momentum:kg*m/s angular_momentum:kg*m^2/s kinetic_energy:J potential_energy:J volume:m^3 \
           max_displacement:m steps:1 time_step:s; do
    [ "$(attr "$f1" "/diagnostics/jelly/${d%%:*}/units")" = "${d#*:}" ] || { echo "no /diagnostics/jelly/${d%%:*} in ${d#*:}"; return 1; }
  done
  for d in bem_steps bem_linear_momentum bem_angular_momentum bem_kinetic_energy bem_potential_energy bem_volume \
           bem_max_displacement; do
    h5dump -H -d "/diagnostics/$d" "$f1" >/dev/null 2>&1 || { echo "no /diagnostics/$d"; return 1; }
  done
  [ $(h5 "$f1" /diagnostics/jelly/steps) = 10 ] && [ $(h5 "$f1" /diagnostics/bem_steps) = 10 ]
}
check "diagnostics per body and /diagnostics/bem_* (10 steps a frame)" diag_ok
check "no NaN or Inf in any frame" bash -c "! (for f in '$bd'/frame.*.h5; do h5dump \"\$f\"; done | grep -Eiq '\\b(nan|inf)\\b')"

# 3. free fall: the frame integrates Ṫ_k = Ṫ_{k−1} + Δt g, T_k = T_{k−1} + Δt Ṫ_k, so after n steps from rest
# T = T₀ + g Δt² n(n+1)/2, with T₀ = R₀x̄ + translate = Rz(90°)(0.03, 0, −0.02) + (0.1, 0.5, −0.05) = (0.1, 0.53, −0.07).
# Error correction may move a drift of u into the frame; a traction-free body has none to speak of, so T stays
# within 1e-3 of the fall distance of that (x̄ comes from the file's single-precision coordinates: ~1e-8 m).
fall_ok() {
  local f T
  for f in 1 2 3; do
    T=$(h5 "$bd/frame.000$f.h5" /jelly/translation)
    awk -v T="$T" -v n=$((10 * f)) 'BEGIN { split(T, t, " "); dt = 1 / 240; fall = -9.81 * dt * dt * n * (n + 1) / 2
      e[1] = 0.1; e[2] = 0.53 + fall; e[3] = -0.07; bad = 0
      for (a = 1; a <= 3; a++) if ((t[a] - e[a])^2 > (1e-3 * fall)^2) bad = 1
      printf "frame %d after %d steps: T = (%.9g, %.9g, %.9g), expected (%.9g, %.9g, %.9g)\n", n / 10, n, t[1], t[2], t[3], e[1], e[2], e[3]
      exit bad }' || return 1
  done
}
check "the centre falls as T₀ + g Δt² n(n+1)/2 (within 1e-3 of the fall)" fall_ok
rot_ok() { # R stays R₀ = Rz(90°): no spin, no torque
  awk -v R="$(h5 "$bd/frame.0003.h5" /jelly/rotation)" 'BEGIN { split(R, r, " "); split("0 -1 0 1 0 0 0 0 1", e, " ")
    for (i = 1; i <= 9; i++) if ((r[i] - e[i])^2 > 1e-18) exit 1 }'
}
check "the rotation stays Rz(90°) of the Transform" rot_ok
small_u() { # |u| ≪ the body's 0.2 m: a free-falling, traction-free body does not deform
  local f m
  for f in 1 2 3; do
    m=$(h5 "$bd/frame.000$f.h5" /diagnostics/jelly/max_displacement)
    awk -v m="$m" 'BEGIN { exit !(m + 0 < 2e-4) }' || { echo "frame $f: max |u| = $m m"; return 1; }
  done
}
check "the displacement stays below 1e-3 of the body's size" small_u
check "progress.jsonl has the BEM steps and seconds of each frame" bash -c "[ \$(grep -c '\"bem_steps\":10,' '$bd/progress.jsonl') -eq 3 ] &&
  [ \$(grep -c '\"bem_history\":[0-9.]*,\"bem_solve\":[0-9.]*,\"bem_correction\":' '$bd/progress.jsonl') -eq 3 ]"
check "report.json sums the BEM steps" grep -q '"steps": 30' "$bd/report.json"

# 4. mesh: each frame's OBJ is V = R(reference + u) + T of its frame cache, with outward unit normals
out=$("$BIN/mesh" "$base" 2>&1); rc=$?
check "mesh writes one OBJ per frame" bash -c "[ $rc -eq 0 ] && [ \$(ls '$md'/jelly.*.obj 2>/dev/null | wc -l) -eq 3 ]"
obj_matches() {
  local f fc
  for f in 1 2 3; do
    fc="$bd/frame.000$f.h5"
    awk -v R="$(h5 "$fc" /jelly/rotation)" -v T="$(h5 "$fc" /jelly/translation)" -v X="$(h5 "$fc" /jelly/reference)" \
        -v U="$(h5 "$fc" /jelly/displacement)" -v tri="$(h5 "$fc" /jelly/triangles)" '
      BEGIN { split(R, r, " "); split(T, t, " "); nx = split(X, x, " "); split(U, u, " "); nt = split(tri, k, " ") }
      /^v / { i = nv++; for (a = 0; a < 3; a++) {
                e = t[a + 1]; for (b = 0; b < 3; b++) e += r[3 * a + b + 1] * (x[3 * i + b + 1] + u[3 * i + b + 1])
                if ((e - $(a + 2))^2 > 1e-14) { printf "vertex %d axis %d: %s, expected %.9g\n", i, a, $(a + 2), e; bad = 1 } } }
      /^vn / { j = nn++; l = $2^2 + $3^2 + $4^2; if ((l - 1)^2 > 1e-10) bad = 1; N[j] = $2 " " $3 " " $4 }
      /^f / { for (c = 2; c <= 4; c++) { split($c, q, "/"); if (q[1] - 1 != k[3 * nf + c - 1]) bad = 1 } nf++ }
      END { if (nv != nx / 3 || nn != nv || nf != nt / 3) { print "counts " nv " " nn " " nf; bad = 1 }
            exit bad }' "$md/jelly.000$f.obj" || { echo "frame $f"; return 1; }
  done
}
check "OBJ vertices are R(reference + u) + T, one unit normal each, the cached triangles" obj_matches
outward() { # the icosphere is convex: every normal points away from the centre T
  awk -v T="$(h5 "$bd/frame.0002.h5" /jelly/translation)" 'BEGIN { split(T, t, " ") }
    /^v / { v[n++] = $2 " " $3 " " $4 } /^vn / { split(v[m++], p, " "); if ((p[1] - t[1]) * $2 + (p[2] - t[2]) * $3 + (p[3] - t[3]) * $4 <= 0) bad = 1 }
    END { exit bad || m != 42 }' "$md/jelly.0002.obj"
}
check "normals point outward" outward
check "every body surface is closed, outward and reloads" "$ROOT/build/tests/objcheck" "$md"/jelly.*.obj
# Transform places the body: frame 1's surface is the file's mesh rotated by Rz(90°), moved by translate and by the
# fall of 10 steps (u is tiny): every vertex within 1e-6 m of one such point
placed() {
  awk 'NR == FNR { if (/^v /) { n++; px[n] = 0.1 - $3; py[n] = 0.5 + $2 - 9.81 * 55 / 240 / 240; pz[n] = $4 - 0.05 } next }
       /^v / { best = 1; for (i = 1; i <= n; i++) { d = ($2 - px[i])^2 + ($3 - py[i])^2 + ($4 - pz[i])^2; if (d < best) best = d }
               if (best > 1e-12) { print "vertex " $0 " is " sqrt(best) " m from the posed file mesh"; bad = 1 } m++ }
       END { exit bad || m != n }' "$S/ico_off.obj" "$md/jelly.0001.obj"
}
check "Transform places the body: frame 1 is the file's mesh rotated, translated and fallen" placed

# 5. render draws the bodies
out=$("$BIN/render" "$base" -j 2 --no-plots 2>&1); rc=$?
check "render draws 3 frames of the body" bash -c "[ $rc -eq 0 ] && [ \$(ls '$rd'/frame.*.png 2>/dev/null | wc -l) -eq 3 ]"

# 6. InitialVelocity: T = T₀ + n Δt v₀ + g Δt² n(n+1)/2 and a spin about y of 90°/s (a sphere keeps its ω, and R turns
# by ω t exactly); neither InitialVelocity nor frame_update and error_correction change the matrices' key
spin=$(mk bem_spin 's#"rotate_deg": \[0, 0, 90\] }#"rotate_deg": [0, 0, 90] }, "InitialVelocity": { "velocity": [1, 2, 0], "angular_velocity": [0, 90, 0] }#')
out=$("$BIN/precompute" "$spin" 2>&1)
check "InitialVelocity leaves the matrices' key alone (a cache hit)" grep -Eq '^precompute: 1 bem body, 1 hit, 0 computed' <<<"$out"
"$BIN/bake" "$spin" --frames 1-1 -q >/dev/null 2>&1
fs="$DRENCH_OUT/bem_spin/bake/frame.0001.h5"
launched() {
  awk -v T="$(h5 "$fs" /jelly/translation)" -v R="$(h5 "$fs" /jelly/rotation)" -v W="$(h5 "$fs" /jelly/angular_velocity)" '
    BEGIN { split(T, t, " "); split(R, r, " "); split(W, w, " "); dt = 1 / 240; n = 10; fall = -9.81 * dt * dt * n * (n + 1) / 2
      e[1] = 0.1 + n * dt; e[2] = 0.53 + 2 * n * dt + fall; e[3] = -0.07
      for (a = 1; a <= 3; a++) if ((t[a] - e[a])^2 > (1e-3 * fall)^2) { print "T " T; bad = 1 }
      pi = atan2(0, -1); c = cos(pi / 2 * n * dt); s = sin(pi / 2 * n * dt)
      split("0 0 0 1 0 0 0 0 0", q, " "); q[2] = -c; q[3] = s; q[8] = s; q[9] = c # Ry(ω t) Rz(90°)
      for (i = 1; i <= 9; i++) if ((r[i] - q[i])^2 > 1e-18) { print "R " R; bad = 1 }
      if ((w[1])^2 + (w[2] - pi / 2)^2 + (w[3])^2 > 1e-20) { print "omega " W; bad = 1 }
      exit bad }'
}
check "InitialVelocity: the frame moves at v₀ under gravity and spins at 90 deg/s = pi/2 rad/s" launched
flags=$(mk bem_flags 's#"frame_update": true#"frame_update": false, "error_correction": false#')
out=$("$BIN/precompute" "$flags" 2>&1)
check "frame_update and error_correction leave the matrices' key alone (a cache hit)" \
  grep -Eq '^precompute: 1 bem body, 1 hit, 0 computed' <<<"$out"

# 7. bad input: exit 2 naming element.Component.field (or the element and key) and the fix; nothing written
odd=$(mk bem_odd 's#"time_step": 0.004166666666666667#"time_step": 0.01#')
pat='bem_odd\.json:[0-9]+:[0-9]+: error: jelly\.BemSolver\.time_step = 0\.01 s does not divide the frame: 1/fps = 1/24 s is 4\.16667 steps.*use 1/96 s = 0\.010416666666666666 \(4 steps per frame at 24 fps\)'
expect_exit "a time step that does not divide the frame: bake exits 2 naming the field and the fix" 2 "$pat" \
  "$BIN/bake" "$odd" --cache "$WORK/cache_odd"
expect_exit "and so does precompute" 2 "$pat" "$BIN/precompute" "$odd" --cache "$WORK/cache_odd"
check "it writes nothing" bash -c "[ ! -e '$DRENCH_OUT/bem_odd' ] && [ ! -e '$WORK/cache_odd' ]"
scaled=$(mk bem_scaled 's#"rotate_deg"#"scale": 2, "rotate_deg"#')
expect_exit "a scaled bem_solid exits 2: scale the OBJ instead" 2 \
  "bem_scaled\.json:[0-9]+:[0-9]+: error: jelly\.Transform\.scale = 2: .*scale the OBJ instead" "$BIN/bake" "$scaled"
check "it writes nothing" test ! -e "$DRENCH_OUT/bem_scaled"
missing=$(mk bem_missing '')
expect_exit "bake without precompute exits 2 naming the element and the key" 2 \
  "jelly: no precomputed BEM matrices for its cache key [0-9a-f]{32} .*run precompute on this scene first" \
  "$BIN/bake" "$missing" --cache "$WORK/cache_empty"
check "it writes nothing" bash -c "[ ! -e '$DRENCH_OUT/bem_missing' ] && [ ! -e '$WORK/cache_empty' ]"

# 8. pipeline.sh runs all four stages on the scene
t=$EPOCHREALTIME
pipe=$(mk bem_pipe '')
out=$("$ROOT/pipeline.sh" --no-build "$pipe" -j 2 2>&1); rc=$?
awk -v a="$t" -v b="$EPOCHREALTIME" 'BEGIN{printf "pipeline on the drop scene took %.1fs\n", b-a}'
[ "$rc" -eq 0 ] || echo "$out" | tail -5
check "pipeline.sh runs precompute, bake, mesh and render on a bem_solid scene" \
  bash -c "[ $rc -eq 0 ] && grep -q 'pipeline: 4 stage(s) ran' <<<'$out' && [ -s '$DRENCH_OUT/bem_pipe/render/contact_sheet.png' ]"
out=$("$ROOT/pipeline.sh" --no-build "$pipe" -j 2 2>&1)
check "and nothing the second time" grep -q "pipeline: 0 stage(s) ran, 4 up to date" <<<"$out"
# the precompute stage's products live in the shared cache, not beside its MANIFEST: with the cache moved away
# the stage is stale (and rebuilds the matrices) rather than up to date with a bake that then cannot start
mv "$DRENCH_CACHE" "$WORK/cache_away"
out=$("$ROOT/pipeline.sh" --no-build "$pipe" -j 2 2>&1); rc=$?
check "a cleared cache makes the precompute stage stale, and pipeline.sh runs it again" \
  bash -c "[ $rc -eq 0 ] && grep -q 'precompute: running (its cache entry bem/[0-9a-f]*.h5 is missing)' <<<'$out' && [ -n \"\$(ls '$DRENCH_CACHE'/bem/*.h5)\" ]"
