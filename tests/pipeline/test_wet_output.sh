# Wet hair in the mesh and render stages, on the shipped two-strand scene cylinder_2 (2 frames): the strands' OBJ
# carries the film's outer radius H = sqrt(r² + A/π) per vertex from the frame cache; mesh.wet_tubes writes closed,
# outward-wound tubes of radius H (none without it, and a clashing element name is refused before anything is
# written); mesh --finish wants every tube; the points carry wet_width; render draws wet hair darker than dry, and
# the preview (the film the bake starts from) as the baked frames.
source "$(dirname "$0")/lib.sh"
mkdir -p "$WORK/scenes"
base="$ROOT/assets/scenes/cylinder_2.json"
# mk NAME [SED]: cylinder_2 for frames 1-2 as shot NAME, edited by SED, into $WORK/scenes/NAME.json
mk() {
  sed 's#"\.\./meshes/#"'"$ROOT"'/assets/meshes/#; s#"frames": \[1, 96\]#"frames": [1, 2]#; s#"name": "cylinder_2"#"name": "'"$1"'"#; '"${2:-}" \
    "$base" > "$WORK/scenes/$1.json"
}
mk wet
mk tubes 's#"render":#"mesh": { "wet_tubes": true },\n  "render":#'
mk dry 's#"HairSolver": { "substeps": 40 },#"HairSolver": { "substeps": 40 } } }#; /"Wetting"/d; /"Film"/d; /"Cohesion"/d'
mk dry_tubes 's#"HairSolver": { "substeps": 40 },#"HairSolver": { "substeps": 40 } } }#; /"Wetting"/d; /"Film"/d; /"Cohesion"/d; s#"render":#"mesh": { "wet_tubes": true },\n  "render":#'
check "the test scenes are edited as meant" bash -c "grep -q '\"frames\": \[1, 2\]' '$WORK/scenes/wet.json' &&
  grep -q wet_tubes '$WORK/scenes/tubes.json' && ! grep -q Wetting '$WORK/scenes/dry.json' && grep -q Wetting '$base' &&
  grep -q wet_tubes '$WORK/scenes/dry_tubes.json' && ! grep -q Wetting '$WORK/scenes/dry_tubes.json'"

"$BIN/precompute" "$WORK/scenes/wet.json" >/dev/null 2>&1
for s in wet tubes; do "$BIN/bake" "$WORK/scenes/$s.json" -j 2 >/dev/null 2>&1 && "$BIN/mesh" "$WORK/scenes/$s.json" -j 2 >/dev/null 2>&1 ||
  fail "$s: bake and mesh run" "$("$BIN/mesh" "$WORK/scenes/$s.json" 2>&1 | tail -2)"; done
wd="$DRENCH_OUT/wet/mesh"; td="$DRENCH_OUT/tubes/mesh"; f2="$DRENCH_OUT/tubes/bake/frame.0002.h5"

# the frame cache's numbers, one per line (h5dump at full precision)
h5vals() { h5dump -y -w 0 -m %.17g -d "$2" "$1" | awk '/DATA \{/{on=1; next} on && /\}/{exit} on { gsub(/,/, " "); for (i = 1; i <= NF; i++) print $i }'; }
h5vals "$f2" /strands/position > "$WORK/x.txt"
h5vals "$f2" /strands/liquid_area > "$WORK/area.txt"
h5vals "$f2" /strands/radius > "$WORK/radius.txt"
check "the frame cache holds 84 vertices with their film" bash -c "[ \$(wc -l < '$WORK/x.txt') -eq 252 ] &&
  [ \$(wc -l < '$WORK/area.txt') -eq 84 ] && [ \$(wc -l < '$WORK/radius.txt') -eq 2 ]"

# 1. mesh: without mesh.wet_tubes no tube; the polylines carry the film either way
check "without mesh.wet_tubes no tube file is written" bash -c "[ -s '$wd/strands.0002.obj' ] && ! ls '$wd'/*_wet* >/dev/null 2>&1"
# outer_radius lines of an OBJ as one number per line, in vertex order
outer() { awk '/^# outer_radius/ { for (i = 3; i <= NF; i++) print $i }' "$1"; }
outer "$wd/strands.0002.obj" > "$WORK/outer_wet.txt"
outer "$td/strands.0002.obj" > "$WORK/outer_tubes.txt"
# H = sqrt(r² + A/π) per vertex from the frame cache (one radius: the strands are not tapered)
awk 'NR == FNR { r = $1; next } { printf "%.17g\n", sqrt(r * r + $1 / 3.14159265358979324) }' \
  "$WORK/radius.txt" "$WORK/area.txt" > "$WORK/H.txt"
check "the film is there to see: H reaches 5 strand radii" awk 'NR == FNR { r = $1; next } $1 > 5 * r { n++ } END { exit !(n > 10) }' \
  "$WORK/radius.txt" "$WORK/H.txt"
# %.9g in the OBJ: 1e-8 relative bounds its rounding
same_h() { awk 'NR == FNR { h[FNR] = $1; next } { d = $1 / h[FNR] - 1; if (d < 0) d = -d; if (d > 1e-8) bad = 1; n++ }
                END { exit !(n == 84 && !bad) }' "$WORK/H.txt" "$1"; }
check "the strands' OBJ gives H = sqrt(r^2 + A/pi) at every vertex (2 strands x 42)" same_h "$WORK/outer_wet.txt"
check "and so with mesh.wet_tubes" same_h "$WORK/outer_tubes.txt"

# 2. the tubes: closed and outward (objcheck: every edge shared by two triangles in opposite directions, positive
#    volume), 8 sides: 2 x 8 triangles per vertex, 8 ring points per vertex and two end centres per strand
check "a tube file per frame" bash -c "[ -s '$td/strands_wet.0001.obj' ] && [ -s '$td/strands_wet.0002.obj' ]"
oc=$("$ROOT/build/tests/objcheck" "$td"/strands_wet.000[12].obj); rc=$?
echo "$oc"
check "the tubes are closed, consistently wound and enclose a positive volume" test "$rc" -eq 0
check "1344 triangles and 676 vertices a frame" bash -c "[ \$(grep -c '676 vertices, 1344 triangles' <<<'$oc') -eq 2 ]"
# ring points of vertex v are OBJ vertices 8v+1 .. 8v+8: each lies H_v from the strand's vertex v; %.9g coordinates
# of up to 0.05 m round by 5e-11 m against H >= 5e-5 m, so 1e-5 relative bounds the rounding
ring_check() {
  awk -v sides=8 'FILENAME ~ /x.txt$/ { x[FNR - 1] = $1; next } FILENAME ~ /H.txt$/ { H[FNR - 1] = $1; next }
    /^v / { p[nv++] = $2 " " $3 " " $4 }
    END {
      split("0 5 20 41 42 63 83", vs, " ")
      for (k in vs) { v = vs[k]
        for (j = 0; j < sides; j++) {
          split(p[v * sides + j], q, " ")
          dx = q[1] - x[3 * v]; dy = q[2] - x[3 * v + 1]; dz = q[3] - x[3 * v + 2]
          d = sqrt(dx * dx + dy * dy + dz * dz); e = d / H[v] - 1; if (e < 0) e = -e
          if (e > 1e-5) { printf "vertex %d ring point %d: %.9g m from the strand, H %.9g m\n", v, j, d, H[v]; bad = 1 }
          n++ } }
      exit !(n == 56 && !bad) }' "$WORK/x.txt" "$WORK/H.txt" "$1"
}
check "ring points lie H from the strand at vertices 0, 5, 20, 41, 42, 63, 83 (frame 2)" ring_check "$td/strands_wet.0002.obj"
check "the hair's points carry wet_width with the film" bash -c "grep -aq wet_width '$td/strands.0002.points.vdb' &&
  grep -aq wet_width '$wd/strands.0002.points.vdb'"
check "mesh summarises the tubes' triangles" bash -c "'$BIN/mesh' '$WORK/scenes/tubes.json' 2>&1 | grep -q '2688 triangles and 4 strands'"

# a scene without wet hair: the option says it does nothing, and the strands' OBJ has no film
"$BIN/bake" "$WORK/scenes/dry_tubes.json" -j 2 >/dev/null 2>&1
out=$("$BIN/mesh" "$WORK/scenes/dry_tubes.json" -j 2 2>&1); rc=$?
check "without wet hair mesh.wet_tubes warns and writes no tube, and no film" bash -c "[ $rc -eq 0 ] &&
  grep -q 'warning: .*mesh.wet_tubes is set but no hair element is wet' <<<'$out' &&
  [ -s '$DRENCH_OUT/dry_tubes/mesh/strands.0002.obj' ] && ! ls '$DRENCH_OUT'/dry_tubes/mesh/*_wet* >/dev/null 2>&1 &&
  ! grep -q outer_radius '$DRENCH_OUT/dry_tubes/mesh/strands.0002.obj'"

# mesh --finish: every frame's tube must be there
rm "$td/strands_wet.0002.obj"
expect_exit "mesh --finish names a missing tube file" 2 "strands_wet\.0002\.obj.*frame 2 of element 'strands' is missing" \
  "$BIN/mesh" "$WORK/scenes/tubes.json" --finish
# an element named <hair>_wet would share the tubes' files: refused before anything is written
cat > "$WORK/scenes/clash.json" <<EOF
{ "shot": { "name": "clash", "fps": 24, "frames": [1, 2] },
  "elements": [
    { "name": "fur", "type": "hair", "components": { "Groom": { "curves": "$ROOT/assets/meshes/cylinder_2.obj" },
      "Wetting": {}, "Film": { "initial_ratio": 3 } } },
    { "name": "fur_wet", "type": "hair", "components": { "Groom": { "curves": "$ROOT/assets/meshes/cylinder_2.obj" },
      "Transform": { "translate": [0.01, 0, 0] } } } ],
  "mesh": { "wet_tubes": true } }
EOF
expect_exit "an element named like a hair's tubes is refused" 2 "mesh\.wet_tubes writes the wet tubes of hair 'fur' as fur_wet\.NNNN\.obj" \
  "$BIN/mesh" "$WORK/scenes/clash.json"
check "and nothing is meshed" test ! -e "$DRENCH_OUT/clash/mesh"

# 3. render: wet hair darker (and wider) than dry, the preview as the baked frames. Luminance over the columns of
#    the strands (they hang at the image's centre) of the preview of the dry scene, of the wet scene and of frame 1.
lum() { "$ROOT/build/tests/pngstat" "$1" 440 0 520 540 | awk '{ printf "%.3f\n", 0.2126 * $2 + 0.7152 * $3 + 0.0722 * $4 }'; }
for s in dry wet; do "$BIN/render" "$WORK/scenes/$s.json" --preview >/dev/null 2>&1; done
"$BIN/render" "$WORK/scenes/wet.json" --no-plots -j 2 >/dev/null 2>&1
l_dry=$(lum "$DRENCH_OUT/dry/preview.png"); l_wet=$(lum "$DRENCH_OUT/wet/preview.png")
l_f1=$(lum "$DRENCH_OUT/wet/render/frame.0001.png")
echo "luminance over the strands' columns: dry preview $l_dry, wet preview $l_wet, wet frame 1 $l_f1"
check "the wet preview is darker than the dry one" awk -v d="$l_dry" -v w="$l_wet" 'BEGIN { exit !(w < d - 1) }'
check "frame 1 of the wet bake looks like the wet preview, not the dry one" \
  awk -v d="$l_dry" -v w="$l_wet" -v f="$l_f1" 'BEGIN { a = f - w; b = f - d; exit !(a * a < b * b) }'
