# Shared helpers of the pipeline tests: each check prints "PASS name" or "FAIL name: why"; the runner counts them.
set -u
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
BIN="$ROOT/bin"
WORK=$(mktemp -d "${TMPDIR:-/tmp}/drench-test.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
export DRENCH_OUT="$WORK/out" DRENCH_CACHE="$WORK/cache" CI=1

pass() { echo "PASS $1"; }
fail() { echo "FAIL $1: $2"; }
# check NAME COMMAND...: passes when the command succeeds
check() { local n="$1"; shift; if "$@"; then pass "$n"; else fail "$n" "command failed: $*"; fi; }
# expect_exit NAME CODE PATTERN COMMAND...: exit code and a stderr pattern (grep -E)
expect_exit() {
  local n="$1" code="$2" pat="$3"; shift 3
  local out rc
  out=$("$@" 2>&1); rc=$?
  if [ "$rc" -ne "$code" ]; then fail "$n" "exit $rc, expected $code; output: $(echo "$out" | head -3)"; return; fi
  if ! echo "$out" | grep -Eq -- "$pat"; then fail "$n" "message lacks /$pat/: $(echo "$out" | head -3)"; return; fi
  pass "$n"
}
# Copies a scene and the meshes it needs into $WORK so tests may edit them.
stage_scene() {
  mkdir -p "$WORK/scenes" "$WORK/meshes"
  cp "$ROOT"/assets/meshes/*.obj "$WORK/meshes/"
  cp "$ROOT/assets/scenes/$1" "$WORK/scenes/$1"
  echo "$WORK/scenes/$1"
}
# h5 FILE DATASET: the dataset's numbers in full precision on one line, separated by spaces
h5() { h5dump -y -w 0 -A 0 -m '%.17g' -d "$2" "$1" 2>/dev/null | awk '/DATA \{/{on=1; next} on && /^ *\}/{on=0} on { gsub(/,/, " "); printf "%s ", $0 } END { print "" }'; }
# same_frames A B SHOT N: bakes A and B (--out folders) of SHOT both hold N frame caches, byte for byte the same
same_frames() {
  local f ok=0
  for f in "$1/$3"/bake/frame.*.h5; do cmp -s "$f" "$2/$3/bake/$(basename "$f")" || { echo "differs: $f"; ok=1; }; done
  [ "$(ls "$1/$3"/bake/frame.*.h5 2>/dev/null | wc -l)" -eq "$4" ] && [ "$(ls "$2/$3"/bake/frame.*.h5 2>/dev/null | wc -l)" -eq "$4" ] && return $ok
}
# same_data A B SHOT N: two bakes' N frame caches hold the same datasets and attributes but the scene key (two scenes
# written differently that must bake the same numbers)
same_data() {
  local f g bad=0
  for f in "$1/$3"/bake/frame.*.h5; do
    g="$2/$3/bake/$(basename "$f")"
    [ -f "$g" ] || { echo "missing: $g"; return 1; }
    h5diff -v "$f" "$g" | awk '/^attribute: |^dataset: /{what=$0} / differences found/{ if ($1 + 0 > 0 && what !~ /scene_key/) { print "differs: " what; bad=1 } } END { exit bad }' || bad=1
  done
  [ "$(ls "$1/$3"/bake/frame.*.h5 2>/dev/null | wc -l)" -eq "$4" ] && [ "$bad" -eq 0 ]
}
# bake_quiet SCENE OUT: bakes on 2 threads (log in OUT.log) without a warning; prints the time
bake_quiet() {
  local t0=$EPOCHREALTIME rc
  "$BIN/bake" "$1" -j 2 --out "$2" >"$2.log" 2>&1; rc=$?
  awk -v a="$t0" -v b="$EPOCHREALTIME" -v n="$(basename "$1" .json)" 'BEGIN { printf "bake %s: %.1f s\n", n, b - a }'
  [ $rc -eq 0 ] && ! grep -qi warn "$2.log"
}
# awk functions for a body's triangle surface, given in its body frame (x: 3 per vertex from index 1, k: 3 vertex
# indices per triangle from 0): face_planes fills N[i, 1..3], the unit normal of face i (outward for a surface wound
# counter-clockwise seen from outside), and O[i] = N[i]·x_a, so O[i] − N[i]·q is the depth of q below face i's plane;
# to_body puts Rᵀ(p_j − T) into q[1..3] (R row-major, T and p as read by h5).
AWK_SURFACE='
function face_planes(x, k, nt,    i, a, b, c, d, e1, e2, nx, ny, nz, l) {
  for (i = 0; i < nt; i++) {
    a = k[3 * i + 1]; b = k[3 * i + 2]; c = k[3 * i + 3]
    for (d = 1; d <= 3; d++) { e1[d] = x[3 * b + d] - x[3 * a + d]; e2[d] = x[3 * c + d] - x[3 * a + d] }
    nx = e1[2] * e2[3] - e1[3] * e2[2]; ny = e1[3] * e2[1] - e1[1] * e2[3]; nz = e1[1] * e2[2] - e1[2] * e2[1]
    l = sqrt(nx * nx + ny * ny + nz * nz); N[i, 1] = nx / l; N[i, 2] = ny / l; N[i, 3] = nz / l
    O[i] = N[i, 1] * x[3 * a + 1] + N[i, 2] * x[3 * a + 2] + N[i, 3] * x[3 * a + 3]
  }
}
function to_body(p, j, r, t, q,    d, v) {
  for (d = 1; d <= 3; d++) v[d] = p[3 * j + d] - t[d]
  for (d = 1; d <= 3; d++) q[d] = r[d] * v[1] + r[3 + d] * v[2] + r[6 + d] * v[3]
}
'
# bem_gaps FRAME-FILE BODY SOLID CONTACT: the distance of each vertex of SOLID (/SOLID/position, hair or cloth) from
# bem_solid BODY's deformed surface x̄ + u (convex: the largest of the face-plane distances, never more than the true
# distance outside), in the body frame q = Rᵀ(p − T). Prints the smallest distance, the vertices within 2·CONTACT and
# the fastest of those.
bem_gaps() {
  local f="$1"
  h5 "$f" "/$3/position" |
  awk -v R="$(h5 "$f" /$2/rotation)" -v T="$(h5 "$f" /$2/translation)" -v X="$(h5 "$f" /$2/reference)" \
      -v U="$(h5 "$f" /$2/displacement)" -v K="$(h5 "$f" /$2/triangles)" -v V="$(h5 "$f" /$3/velocity)" -v C="$4" \
      "$AWK_SURFACE"'BEGIN {
    split(R, r, " "); split(T, t, " "); split(X, x, " "); split(U, u, " "); nt = split(K, k, " ") / 3
    for (i in x) x[i] += u[i]
    face_planes(x, k, nt)
    split(V, vel, " ") }
  { np = split($0, p, " ") / 3; gmin = 1e9; near = 0; vmax = 0
    for (j = 0; j < np; j++) {
      to_body(p, j, r, t, q)
      g = -1e9
      for (i = 0; i < nt; i++) { s = N[i, 1] * q[1] + N[i, 2] * q[2] + N[i, 3] * q[3] - O[i]; if (s > g) g = s }
      if (g < gmin) gmin = g
      if (g < 2 * C) { near++; sp = sqrt(vel[3*j+1]^2 + vel[3*j+2]^2 + vel[3*j+3]^2); if (sp > vmax) vmax = sp }
    }
    printf "%.6e %d %.3e\n", gmin, near, vmax }'
}
