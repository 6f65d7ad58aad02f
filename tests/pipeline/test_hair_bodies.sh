#!/usr/bin/env bash
# Hair rests on the solids it falls on: a strand clamped 3 mm above the top of a bem_solid icosphere (radius 0.1 m,
# its lower half held by FixedVertices) droops onto it and over its side (tests/data/hair_drape_bem.json); a strand
# held over an elastic mpm_solid block resting on the floor droops onto the block (tests/data/hair_drape_mpm.json).
# After 1.5 s no vertex is deeper into the contact layer (strand radius + Collider.thickness = 1.05 mm) than 10 % of
# it, the strand touches the solid over several vertices, and those have come to rest.
source "$(dirname "$0")/lib.sh"
# h5 FILE DATASET: its numbers in full precision, one line
h5() { h5dump -y -w 0 -A 0 -m '%.17g' -d "$2" "$1" 2>/dev/null | awk '/DATA \{/{on=1; next} on && /^ *\}/{on=0} on { gsub(/,/, " "); printf "%s ", $0 } END { print "" }'; }
CONTACT=0.00105 # strand radius 5e-5 m + Collider.thickness 1e-3 m

rests() { # NAME GAPS: the gap, the contact and the rest
  local g n v
  read -r g n v <<<"$2"
  echo "$1: closest vertex $g m from the surface (contact at $CONTACT m), $n vertices within 2x, the fastest of them $v m/s"
  awk -v g="$g" -v n="$n" -v v="$v" -v C=$CONTACT 'BEGIN { exit !(g >= 0.9 * C && n >= 3 && v < 0.01) }'
}

scene="$ROOT/tests/data/hair_drape_bem.json"
"$BIN/precompute" "$scene" -j 2 >/dev/null 2>&1
out=$("$BIN/bake" "$scene" -j 2 --out "$WORK/bem" 2>&1); rc=$?
[ "$rc" -eq 0 ] || echo "$out" | tail -5
check "a strand over a bem_solid bakes" test "$rc" -eq 0
check "the hair sees the bem_solid body" grep -q "the hair sees 1 bem_solid body" <<<"$out"
gaps=$(bem_gaps "$WORK/bem/hair_drape_bem/bake/frame.0036.h5" rock strand $CONTACT)
check "the strand rests on the bem_solid's deformed surface, no deeper than 10% of the contact thickness" rests "bem_solid" "$gaps"

# Distance of each strand vertex from an mpm_solid's particles, each the ball of radius r = ½ V^(1/3) (V its volume:
# balls of neighbours on the lattice touch), smallest over the particles: prints the smallest distance; and, to
# count the vertices lying on the body, the distance from the union of the particles' cubes of edge 2r (the block's
# faces, where the balls leave dips between them), the vertices within 2·CONTACT of it and the fastest of those
# by their mean speed over the last 0.25 s (the contact chatters at ~2 cm/s against the rebuilt particle surface
# while the vertices stay within a fraction of a millimetre).
mpm_gaps() { # FRAME-FILE BODY HAIR EARLIER-FRAME-FILE
  local f="$1" d="$WORK/gaps"; mkdir -p "$d"
  h5 "$f" "/$2/position" >"$d/p"; h5 "$f" "/$2/volume" >"$d/w"; h5 "$f" "/$3/position" >"$d/h"; h5 "$4" "/$3/position" >"$d/v"
  awk -v C=$CONTACT 'FILENAME == ARGV[1] { np = split($0, x, " ") / 3 } FILENAME == ARGV[2] { split($0, w, " ") }
    FILENAME == ARGV[3] { nh = split($0, p, " ") / 3 } FILENAME == ARGV[4] { split($0, vel, " ") }
    END {
      for (i = 1; i <= np; i++) r[i] = 0.5 * w[i] ^ (1 / 3)
      gmin = 1e9; near = 0; vmax = 0
      for (j = 0; j < nh; j++) {
        ball = 1e9; cube = 1e9
        for (i = 1; i <= np; i++) {
          out = 0; ins = -1e9
          for (a = 1; a <= 3; a++) { e = p[3*j+a] - x[3*(i-1)+a]; e = (e < 0 ? -e : e) - r[i]; if (e > 0) out += e * e; if (e > ins) ins = e }
          c = ins < 0 ? ins : sqrt(out); if (c < cube) cube = c
          b = sqrt((p[3*j+1] - x[3*i-2])^2 + (p[3*j+2] - x[3*i-1])^2 + (p[3*j+3] - x[3*i])^2) - r[i]; if (b < ball) ball = b
        }
        if (ball < gmin) gmin = ball
        if (cube < 2 * C) { near++; sp = sqrt((p[3*j+1] - vel[3*j+1])^2 + (p[3*j+2] - vel[3*j+2])^2 + (p[3*j+3] - vel[3*j+3])^2) / 0.25; if (sp > vmax) vmax = sp }
      }
      printf "%.6e %d %.3e\n", gmin, near, vmax }' "$d/p" "$d/w" "$d/h" "$d/v"
}
scene="$ROOT/tests/data/hair_drape_mpm.json"
out=$("$BIN/bake" "$scene" -j 2 --out "$WORK/mpm" 2>&1); rc=$?
[ "$rc" -eq 0 ] || echo "$out" | tail -5
check "a strand over an mpm_solid bakes" test "$rc" -eq 0
gaps=$(mpm_gaps "$WORK/mpm/hair_drape_mpm/bake/frame.0036.h5" block strand "$WORK/mpm/hair_drape_mpm/bake/frame.0030.h5")
check "the strand rests on the mpm_solid's particles, no deeper than 10% of the contact thickness" rests "mpm_solid" "$gaps"
