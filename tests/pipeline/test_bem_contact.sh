# BEM bodies meet colliders, each other, fixed vertices and joints in a bake (BEM §3.4). tests/data/bem_floor.json
# drops a 42-vertex icosphere face down onto a floor collider (ground.obj, top at y = 0) and a second one onto a
# third resting on the floor; tests/data/bem_joint.json hangs a body by its top vertices and joins two free bodies at
# one vertex ("point" mode), one of them launched sideways and up. Checks: no vertex below the floor by more than the
# contact thickness, the dropped body comes to rest, bodies stay apart, the frame cache holds the constraint figures,
# fixed vertices stay put, the joined vertices stay together, bad input exits 2 naming element.component.field and
# writes nothing, and a bake with contact is bit-identical on 1 and 2 threads and when resumed.
source "$(dirname "$0")/lib.sh"
floor="$ROOT/tests/data/bem_floor.json"; joint="$ROOT/tests/data/bem_joint.json"
fd="$DRENCH_OUT/bem_floor/bake"; jd="$DRENCH_OUT/bem_joint/bake"
# h5 FILE DATASET: its numbers in full precision, one line
h5() { h5dump -y -w 0 -A 0 -m '%.17g' -d "$2" "$1" 2>/dev/null | awk '/DATA \{/{on=1; next} on && /^ *\}/{on=0} on { gsub(/,/, " "); printf "%s ", $0 } END { print "" }'; }
# verts FILE BODY: the body's world vertices V = R(reference + u) + T, one "x y z" per line
verts() {
  awk -v R="$(h5 "$1" "/$2/rotation")" -v T="$(h5 "$1" "/$2/translation")" -v X="$(h5 "$1" "/$2/reference")" \
      -v U="$(h5 "$1" "/$2/displacement")" 'BEGIN { split(R, r, " "); split(T, t, " "); n = split(X, x, " "); split(U, u, " ")
    for (i = 0; i < n / 3; i++) { line = ""
      for (a = 0; a < 3; a++) { e = t[a + 1]; for (b = 0; b < 3; b++) e += r[3 * a + b + 1] * (x[3 * i + b + 1] + u[3 * i + b + 1])
                                line = line sprintf("%.17g ", e) }
      print line } }'
}

# 1. precompute (the five bodies share one matrix set) and bake both scenes
out=$("$BIN/precompute" "$floor" -j 2 2>&1); rc=$?
built_once() { [ "$rc" -eq 0 ] && grep -q '^precompute: 3 bem bodies, 0 hits, 1 computed' <<<"$out" &&
               [ "$(grep -c 'same matrices as jelly' <<<"$out")" -eq 2 ]; }
check "precompute builds the matrices once for the three bodies" built_once
"$BIN/precompute" "$joint" -q >/dev/null 2>&1
t=$EPOCHREALTIME
out=$("$BIN/bake" "$floor" -j 2 2>&1); rc=$?
awk -v a="$t" -v b="$EPOCHREALTIME" 'BEGIN{printf "bake of the floor scene (16 frames, 3 bodies) took %.1fs\n", b-a}'
[ "$rc" -eq 0 ] || echo "$out" | tail -5
check "the floor scene bakes 16 frames" bash -c "[ $rc -eq 0 ] && [ \$(ls '$fd'/frame.*.h5 2>/dev/null | wc -l) -eq 16 ]"
together() { grep -q "bem: 3 bodies with steps of 0.00416667 s stepped together: 1 collider(s), 0 fixed vertices, 0 joint pair(s), body contact on, thickness 0.001 m, friction 0.5" <<<"$out"; }
check "the three bodies are stepped together with the floor and body contact" together
out=$("$BIN/bake" "$joint" -j 2 2>&1); rc=$?
[ "$rc" -eq 0 ] || echo "$out" | tail -5
check "the joint scene bakes 8 frames" bash -c "[ $rc -eq 0 ] && [ \$(ls '$jd'/frame.*.h5 2>/dev/null | wc -l) -eq 8 ]"
selected() { grep -q 'bem: hanger: 7 of 42 vertices fixed' <<<"$out" &&
             grep -q 'bem: hinge: joins vertex [0-9]* of left and vertex [0-9]* of right' <<<"$out"; }
check "FixedVertices holds the hanger's 7 top vertices; the hinge joins one vertex pair" selected

# 2. the floor: the constraint keeps every vertex at sdf >= thickness = 1 mm up to the solver's tolerance (1e-7 m); the
# floor's top face is a plane, which the SDF's trilinear interpolation reproduces exactly, so 1e-6 m is ample
above_floor() {
  local f b m
  for f in "$fd"/frame.*.h5; do
    for b in jelly base topper; do
      m=$(verts "$f" $b | awk 'BEGIN { m = 1e9 } { if ($2 < m) m = $2 } END { printf "%.9g", m }')
      awk -v m="$m" 'BEGIN { exit !(m >= 0.001 - 1e-6) }' || { echo "$(basename "$f") $b: lowest vertex at y = $m m"; return 1; }
    done
  done
}
check "no vertex of any body comes below the floor by more than the thickness (y >= 1 mm - 1e-6 m) in any frame" above_floor
check "no NaN or Inf in any frame" bash -c "! (for f in '$fd'/frame.*.h5 '$jd'/frame.*.h5; do h5dump \"\$f\"; done | grep -Eiq '\\b(nan|inf)\\b')"
# The jelly falls 25 mm onto the floor (m g h = 3.66 kg × 9.81 × 0.025 m ≈ 0.9 J) and lands in frame 2. The body has
# no material damping, so it keeps a small elastic rocking; at rest means: in the last four frames its frame's kinetic
# energy is below 1e-3 J (0.1% of the fall), its lowest vertex within 0.1 mm of the 1 mm offset, its centre within
# 2 mm of where it landed (0.0935 m = the centre's height over its lowest face vertices, plus the offset)
at_rest() {
  local f ke m T
  for f in 13 14 15 16; do
    ke=$(h5 "$fd/frame.00$f.h5" /diagnostics/jelly/kinetic_energy)
    m=$(verts "$fd/frame.00$f.h5" jelly | awk 'BEGIN { m = 1e9 } { if ($2 < m) m = $2 } END { printf "%.9g", m }')
    T=$(h5 "$fd/frame.00$f.h5" /jelly/translation)
    awk -v ke="$ke" -v m="$m" -v T="$T" 'BEGIN { split(T, t, " ")
      ok = ke + 0 < 1e-3 && m - 0.001 < 1e-4 && (t[2] - 0.0945)^2 < 2e-3^2 && t[1]^2 + t[3]^2 < 0.01^2
      if (!ok) printf "kinetic %s J, lowest vertex %s m, centre %s\n", ke, m, T; exit !ok }' || { echo "frame $f"; return 1; }
  done
}
check "the dropped body comes to rest on the floor" at_rest
# topper lands on base: the two icospheres (radius 0.1 m, 0.0934 m from centre to the flat of a subdivided face) keep
# their centres more than 0.18 m apart, and the frame cache counts the body-body contacts
apart() {
  local f
  for f in "$fd"/frame.*.h5; do
    awk -v A="$(h5 "$f" /base/translation)" -v B="$(h5 "$f" /topper/translation)" 'BEGIN { split(A, a, " "); split(B, b, " ")
      d = sqrt((a[1] - b[1])^2 + (a[2] - b[2])^2 + (a[3] - b[3])^2); if (d < 0.18) { print "centres " d " m apart"; exit 1 } }' ||
      { echo "$(basename "$f")"; return 1; }
  done
}
check "a body dropped on another stays outside it (centres > 0.18 m apart)" apart
touched() { for f in "$fd"/frame.*.h5; do awk -v n="$(h5 "$f" /diagnostics/bem_body_contacts)" 'BEGIN { exit !(n > 0) }' && return 0; done; return 1; }
check "body-body contacts are active in some frame" touched
diag_ok() {
  local d f="$fd/frame.0008.h5"
  for d in bem_contacts bem_body_contacts bem_sticking bem_fixed bem_joints bem_pgs_iterations bem_passes bem_residual \
           bem_not_converged; do
    h5dump -H -d "/diagnostics/$d" "$f" >/dev/null 2>&1 || { echo "no /diagnostics/$d"; return 1; }
  done
  awk -v c="$(h5 "$f" /diagnostics/bem_contacts)" -v i="$(h5 "$f" /diagnostics/bem_pgs_iterations)" \
      -v r="$(h5 "$f" /diagnostics/bem_residual)" 'BEGIN { exit !(c >= 3 && i > 0 && r + 0 < 1e-6) }'
}
check "the frame cache holds the constraint figures (contacts with the floor, PGS sweeps, residual < 1e-6 m)" diag_ok

# 3. fixed vertices: the hanger's vertices inside its box at t = 0 (the file's vertices moved by its translate
# (0.5, 0.5, 0)) stay within 1e-6 m of where they started in every frame, while the rest of it sags under gravity.
# The frame cache may order the vertices differently from the file: each file vertex is matched to the cached one
# whose reference x − x̄ is nearest (x̄ of the centred icosphere is ~1e-8 m, its vertices 0.06 m apart)
held() {
  local f
  for f in "$jd"/frame.*.h5; do
    { sed -n 's/^v //p' "$ROOT/tests/data/bem_ico1.obj"; echo "--"; h5 "$f" /hanger/reference | xargs -n 3; echo "--"; verts "$f" hanger; } |
    awk -v out="$(basename "$f")" 'BEGIN { nf = nr = nv = part = 0 } /^--/ { part++; next }
      part == 0 { x[nf] = $1 + 0.5; y[nf] = $2 + 0.5; z[nf] = $3; fx[nf] = $1; fy[nf] = $2; fz[nf++] = $3; next }
      part == 1 { rx[nr] = $1; ry[nr] = $2; rz[nr++] = $3; next }
      { vx[nv] = $1; vy[nv] = $2; vz[nv++] = $3 }
      END { for (i = 0; i < nf; i++) { if (y[i] < 0.58 || y[i] > 0.7) continue; k++; best = 1e9
              for (j = 0; j < nr; j++) { d = (rx[j] - fx[i])^2 + (ry[j] - fy[i])^2 + (rz[j] - fz[i])^2; if (d < best) { best = d; c = j } }
              d = sqrt((vx[c] - x[i])^2 + (vy[c] - y[i])^2 + (vz[c] - z[i])^2)
              if (d > 1e-6) { print out ": vertex " i " moved " d " m"; bad = 1 } }
            if (k != 7) { print out ": " k " vertices in the box"; bad = 1 } exit bad }' || return 1
  done
}
check "FixedVertices: the held vertices stay within 1e-6 m of their start" held
sagged() { awk -v T="$(h5 "$jd/frame.0008.h5" /hanger/translation)" 'BEGIN { split(T, t, " "); exit !(t[2] < 0.5 - 1e-5 && t[2] > 0.49) }'; }
check "and the hanger hangs from them (its centre sags by more than 10 um, less than 1 cm)" sagged
# the hinge: the closest pair of a vertex of left and a vertex of right stays within 1e-5 m (100 × the solver's
# position tolerance of 1e-7 m, the residual the frame cache reports) in every frame, while left, launched at
# (0, 0.5, 0.5) m/s, drags right along: the joint's forces are equal and opposite and nothing else pushes along z, so
# the pair's z momentum stays that of the launch (equal masses: v_z(left) + v_z(right) = 0.5 m/s, within 1%) and right,
# which starts at rest, moves along z
joined() {
  local f
  for f in "$jd"/frame.*.h5; do
    { verts "$f" left; echo "--"; verts "$f" right; } | awk -v out="$(basename "$f")" '/^--/ { sep = 1; next }
      !sep { a[na++] = $0; next } { b[nb++] = $0 }
      END { m = 1e9; for (i = 0; i < na; i++) { split(a[i], p, " "); for (j = 0; j < nb; j++) { split(b[j], q, " ")
              d = (p[1] - q[1])^2 + (p[2] - q[2])^2 + (p[3] - q[3])^2; if (d < m) m = d } }
            if (sqrt(m) > 1e-5) { print out ": joined vertices " sqrt(m) " m apart"; exit 1 } }' || return 1
  done
}
check "a point joint keeps the two bodies together (joined vertices within 1e-5 m in every frame)" joined
dragged() {
  local f
  for f in "$jd"/frame.*.h5; do
    awk -v L="$(h5 "$f" /left/velocity)" -v R="$(h5 "$f" /right/velocity)" 'BEGIN { split(L, l, " "); split(R, r, " ")
      ok = r[3] > 0.05 && (l[3] + r[3] - 0.5)^2 < 0.005^2; if (!ok) print "v_z " l[3] " and " r[3]; exit !ok }' ||
      { echo "$(basename "$f")"; return 1; }
  done
}
check "the joint drags the second body along (v_z > 0.05 m/s) and keeps the pair's z momentum (1%)" dragged

# 4. bad input: exit 2, naming element.Component.field, writing nothing
S="$WORK/scenes"; mkdir -p "$S"; cp "$ROOT/tests/data/bem_ico1.obj" "$S/"
sed 's#"name": "bem_joint"#"name": "bem_empty_box"#; s#\[\[0.3, 0.58, -0.2\], \[0.7, 0.7, 0.2\]\]#[[2, 2, 2], [3, 3, 3]]#' "$joint" > "$S/empty_box.json"
expect_exit "an empty FixedVertices box exits 2 naming the field" 2 \
  "hanger\.FixedVertices\.box = \[\[2, 2, 2\], \[3, 3, 3\]\] holds none of the body's 42 vertices" \
  "$BIN/bake" "$S/empty_box.json"
check "it writes nothing" test ! -e "$DRENCH_OUT/bem_empty_box"
sed 's#"name": "bem_joint"#"name": "bem_bad_joint"#; s#"body_b": "right"#"body_b": "rihgt"#' "$joint" > "$S/bad_joint.json"
expect_exit "an unknown joint body exits 2 naming the field and the likely name" 2 \
  "bad_joint\.json:[0-9]+:[0-9]+: error: hinge\.Joint\.body_b = 'rihgt': no bem_solid element has this name; did you mean 'right'\?" \
  "$BIN/bake" "$S/bad_joint.json"
check "it writes nothing" test ! -e "$DRENCH_OUT/bem_bad_joint"
sed 's#"name": "bem_joint"#"name": "bem_not_body"#; s#"body_a": "left"#"body_a": "hinge"#' "$joint" > "$S/not_body.json"
expect_exit "a joint naming an element that is no bem_solid exits 2" 2 \
  "hinge\.Joint\.body_a = 'hinge' is a bem_joint element, not a bem_solid" "$BIN/bake" "$S/not_body.json"
sed 's#"name": "bem_joint"#"name": "bem_no_point"#; s#"point": \[-0.4149349191648, 0.5, 0.0525731112119\]#"tolerance": 1e-6#' "$joint" > "$S/no_point.json"
expect_exit "mode point without a point exits 2" 2 "hinge\.Joint\.point is required with mode \"point\"" \
  "$BIN/bake" "$S/no_point.json"

# 5. determinism with contact active: 1 vs 2 threads, and stopped after frame 6 and resumed
d1="$WORK/d1"; d2="$WORK/d2"; d3="$WORK/d3"
"$BIN/bake" "$floor" -j 1 --out "$d1" -q >/dev/null 2>&1
"$BIN/bake" "$floor" -j 2 --out "$d2" -q >/dev/null 2>&1
same() { local f ok=0; for f in "$1"/bem_floor/bake/frame.*.h5; do cmp -s "$f" "$2/bem_floor/bake/$(basename "$f")" || { echo "differs: $f"; ok=1; }; done
         [ "$(ls "$1"/bem_floor/bake/frame.*.h5 | wc -l)" -eq 16 ] && return $ok; }
check "a bake with contact on 1 and on 2 threads is bit-identical" same "$d1" "$d2"
"$BIN/bake" "$floor" -j 2 --frames 1-6 --out "$d3" -q >/dev/null 2>&1
"$BIN/bake" "$floor" -j 2 --out "$d3" --resume >"$WORK/resume.log" 2>&1
check "the contact bake resumes after frame 6" grep -q "resuming after frame 6" "$WORK/resume.log"
check "a resumed contact bake is bit-identical to an uninterrupted one" same "$d2" "$d3"
