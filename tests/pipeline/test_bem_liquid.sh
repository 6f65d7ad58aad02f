#!/usr/bin/env bash
# A bem_solid body is a moving collider of the liquid (one-way): tests/data/bem_liquid.json drops the 42-vertex
# icosphere (radius 0.1 m) from rest into a 0.2 m deep pool of a 0.4 m box. By frame 5 its centre is 0.07 m under
# the rest surface: no liquid particle is left inside the body's posed rest shape (more than half a cell deep), the
# liquid is displaced upwards, and the bake is bit-identical on 1 and 2 threads and when resumed.
source "$(dirname "$0")/lib.sh"
scene="$ROOT/tests/data/bem_liquid.json"
# h5 FILE DATASET: its numbers in full precision, one line
h5() { h5dump -y -w 0 -A 0 -m '%.17g' -d "$2" "$1" 2>/dev/null | awk '/DATA \{/{on=1; next} on && /^ *\}/{on=0} on { gsub(/,/, " "); printf "%s ", $0 } END { print "" }'; }

out=$("$BIN/precompute" "$scene" -j 2 2>&1); rc=$?
built() { [ "$rc" -eq 0 ] && grep -Eq '^precompute: 1 bem body' <<<"$out"; }
check "precompute builds the body's matrices" built
b1="$WORK/b1"; b2="$WORK/b2"; b3="$WORK/b3"
t=$EPOCHREALTIME
out=$("$BIN/bake" "$scene" -j 2 --out "$b2" 2>&1); rc=$?
awk -v a="$t" -v b="$EPOCHREALTIME" 'BEGIN{printf "bake of 5 frames took %.1fs\n", b-a}'
[ "$rc" -eq 0 ] || echo "$out" | tail -5
bd="$b2/bem_liquid/bake"
baked() { [ "$rc" -eq 0 ] && [ "$(ls "$bd"/frame.*.h5 2>/dev/null | wc -l)" -eq 5 ]; }
check "bake exits 0 and writes 5 frame caches" baked
check "the liquid sees the body as a moving collider" grep -q "the liquid sees 1 bem_solid body as moving collider" <<<"$out"

# Depth of every particle inside the posed rest shape: the icosphere is convex, so a point p is inside by
# min over faces f of (n_f·x_f − n_f·q), q = Rᵀ(p − T) in the body frame, x_f a vertex of f (positive inside).
deepest() { # FRAME: prints the largest depth (m) and the particles deeper than 0.01 m
  local f="$bd/frame.000$1.h5"
  h5 "$f" /water/position |
  awk -v R="$(h5 "$f" /jelly/rotation)" -v T="$(h5 "$f" /jelly/translation)" -v X="$(h5 "$f" /jelly/reference)" \
      -v K="$(h5 "$f" /jelly/triangles)" "$AWK_SURFACE"'BEGIN {
    split(R, r, " "); split(T, t, " "); split(X, x, " "); nt = split(K, k, " ") / 3
    face_planes(x, k, nt) }
  { np = split($0, p, " ") / 3
    worst = -1; deep = 0
    for (j = 0; j < np; j++) {
      to_body(p, j, r, t, q)
      m = 1
      for (i = 0; i < nt && m > -0.02; i++) { s = O[i] - (N[i, 1] * q[1] + N[i, 2] * q[2] + N[i, 3] * q[3]); if (s < m) m = s }
      if (m > worst) worst = m
      if (m > 0.01) deep++
    }
    printf "%.6f %d\n", worst, deep }'
}
inside_ok() {
  local d
  d=$(deepest 5); echo "frame 5: deepest particle $(cut -d' ' -f1 <<<"$d") m inside the body, $(cut -d' ' -f2 <<<"$d") deeper than 0.01 m"
  [ "$(cut -d' ' -f2 <<<"$d")" -eq 0 ]
}
check "no liquid particle more than half a cell (0.01 m) inside the posed body in frame 5" inside_ok
submerged() { # the body really is in the pool: its centre below the rest surface (y = 0.2) by more than 0.05 m
  awk -v T="$(h5 "$bd/frame.0005.h5" /jelly/translation)" 'BEGIN { split(T, t, " "); printf "frame 5: centre y = %.4f m\n", t[2]; exit !(t[2] < 0.15) }'
}
check "the body is submerged by frame 5" submerged
mean_y() { h5 "$1" /water/position | awk '{ s = 0; for (i = 2; i <= NF; i += 3) s += $i; printf "%.6f", s / (NF / 3) }'; }
rises() {
  local y1 y5
  y1=$(mean_y "$bd/frame.0001.h5"); y5=$(mean_y "$bd/frame.0005.h5")
  echo "mean particle height: frame 1 $y1 m, frame 5 $y5 m"
  # the body displaces ~3.6e-3 m³ of the 0.4 × 0.4 m pool: the level rises ~0.02 m, the mean height ~0.01 m
  awk -v a="$y1" -v b="$y5" 'BEGIN { exit !(b > a + 0.005) }'
}
check "the displaced liquid rises (mean particle height up by more than 5 mm)" rises

"$BIN/bake" "$scene" -j 1 --out "$b1" -q >/dev/null 2>&1
same() { local f ok=0; for f in "$1"/bem_liquid/bake/frame.*.h5; do cmp -s "$f" "$2/bem_liquid/bake/$(basename "$f")" || { echo "differs: $f"; ok=1; }; done
         [ "$(ls "$1"/bem_liquid/bake/frame.*.h5 | wc -l)" -eq 5 ] && return $ok; }
check "the bake is bit-identical on 1 and 2 threads" same "$b1" "$b2"
"$BIN/bake" "$scene" -j 2 --frames 1-3 --out "$b3" -q >/dev/null 2>&1
"$BIN/bake" "$scene" -j 2 --out "$b3" --resume >"$WORK/resume.log" 2>&1
check "the bake resumes after frame 3" grep -q "resuming after frame 3" "$WORK/resume.log"
check "a resumed bake is bit-identical to an uninterrupted one" same "$b2" "$b3"

# A squashed body: tests/data/bem_squash.json holds the bottom of a soft icosphere (μ = 3 kPa) in the pool and throws
# the rest of it down at 2.5 m/s, so its surface moves by up to ~0.07 m (0.7 of its radius). The liquid sees its
# deformed surface, updated at every BEM step: in the frame of the largest displacement, no particle is more than
# half a cell (0.01 m) inside the deformed surface x̄ + u, posed by R and T. Inside is the solid angle the
# triangles subtend (the winding number, exact for any closed surface, convex or not), for the particles in the
# body's box; depth is the distance to the nearest vertex plane, which for these small faces is within a few mm.
squash="$ROOT/tests/data/bem_squash.json"
"$BIN/precompute" "$squash" -j 2 >/dev/null 2>&1
"$BIN/bake" "$squash" -j 2 --out "$WORK/sq" -q >/dev/null 2>&1; rc=$?
sd="$WORK/sq/bem_squash/bake"
check "a squashed body bakes" test "$rc" -eq 0
squashed_inside() { # FRAME: prints the particles inside the deformed surface and the deepest of them
  local f="$sd/frame.000$1.h5" d="$WORK/sqd"; mkdir -p "$d"
  h5 "$f" /water/position >"$d/p"
  awk -v R="$(h5 "$f" /jelly/rotation)" -v T="$(h5 "$f" /jelly/translation)" -v X="$(h5 "$f" /jelly/reference)" \
      -v U="$(h5 "$f" /jelly/displacement)" -v K="$(h5 "$f" /jelly/triangles)" "$AWK_SURFACE"'BEGIN {
    split(R, r, " "); split(T, t, " "); nx = split(X, x, " "); split(U, u, " "); nt = split(K, k, " ") / 3
    for (d = 1; d <= 3; d++) { lo[d] = 1e9; hi[d] = -1e9 }
    for (i = 0; i < nx / 3; i++)
      for (d = 1; d <= 3; d++) { x[3*i+d] += u[3*i+d]; if (x[3*i+d] < lo[d]) lo[d] = x[3*i+d]; if (x[3*i+d] > hi[d]) hi[d] = x[3*i+d] }
    face_planes(x, k, nt) }
  { np = split($0, p, " ") / 3; inside = 0; worst = 0
    for (j = 0; j < np; j++) {
      to_body(p, j, r, t, q)
      out = 0
      for (d = 1; d <= 3; d++) if (q[d] < lo[d] || q[d] > hi[d]) out = 1
      if (out) continue
      w = 0; dmin = 1e9
      for (i = 0; i < nt; i++) { # solid angle of triangle i seen from q (Van Oosterom and Strackee)
        for (c = 0; c < 3; c++) { vi = k[3 * i + c + 1]; for (d = 1; d <= 3; d++) A[c, d] = x[3 * vi + d] - q[d]
          L[c] = sqrt(A[c, 1]^2 + A[c, 2]^2 + A[c, 3]^2); if (L[c] < dmin) dmin = L[c] }
        det = A[0,1] * (A[1,2] * A[2,3] - A[1,3] * A[2,2]) - A[0,2] * (A[1,1] * A[2,3] - A[1,3] * A[2,1]) + A[0,3] * (A[1,1] * A[2,2] - A[1,2] * A[2,1])
        den = L[0] * L[1] * L[2] + (A[0,1]*A[1,1] + A[0,2]*A[1,2] + A[0,3]*A[1,3]) * L[2] + (A[0,1]*A[2,1] + A[0,2]*A[2,2] + A[0,3]*A[2,3]) * L[1] + (A[1,1]*A[2,1] + A[1,2]*A[2,2] + A[1,3]*A[2,3]) * L[0]
        w += 2 * atan2(det, den)
      }
      if (w > 6.2831853) { # winding number 1: inside; its depth below the nearest face plane
        m = 1e9
        for (i = 0; i < nt; i++) { s = O[i] - (N[i, 1] * q[1] + N[i, 2] * q[2] + N[i, 3] * q[3]); if (s >= 0 && s < m) m = s }
        if (m < 1e9 && m > 0.01) inside++
        if (m < 1e9 && m > worst) worst = m
      }
    }
    printf "%d %.4f\n", inside, worst }' "$d/p"
}
squash_ok() {
  local best=0 bf=1 f m
  for f in 1 2 3 4 5 6 7 8; do
    m=$(h5 "$sd/frame.000$f.h5" /diagnostics/jelly/max_displacement)
    awk -v a="$m" -v b="$best" 'BEGIN { exit !(a > b) }' && { best=$m; bf=$f; }
  done
  local r; r=$(squashed_inside "$bf")
  echo "squashed body: largest displacement $best m in frame $bf; particles deeper than 0.01 m inside its deformed surface: $(cut -d' ' -f1 <<<"$r") (deepest $(cut -d' ' -f2 <<<"$r") m)"
  awk -v a="$best" 'BEGIN { exit !(a > 0.05) }' && [ "$(cut -d' ' -f1 <<<"$r")" -eq 0 ]
}
check "a squashed body (displacement > 0.05 m) keeps the liquid out of its deformed surface" squash_ok
