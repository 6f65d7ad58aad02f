# Hair coupled with a fluid (Drag): the shipped scenes fur_tank (a furry ball swept through a tank of liquid) and
# fur_wind (a furry ball in the air element's wind), a few frames each. A bake on 1 and on 2 threads, and one stopped
# after frame 2 and resumed, give bit-identical frames; each frame's momentum ledger (what the hair received plus what
# the fluid was given) sums to zero per axis to 1e-12 of the larger of the two, the coupled loop ran and the hair was
# pushed the way the fluid moves relative to it. Bad Drag input is in test_bad_input.sh.
source "$(dirname "$0")/lib.sh"
h5num() { # file dataset: its first value, to 17 digits
  h5dump -m "%.17g" -d "$2" "$1" 2>/dev/null | awk '/\(0\):/{sub(/^.*\(0\): */, ""); sub(/,.*$/, ""); print; exit}'
}
same_frames() { # dir1 dir2 shot count
  local f ok=0
  [ "$(ls "$1/$3"/bake/frame.*.h5 2>/dev/null | wc -l)" -eq "$4" ] || { echo "expected $4 frames in $1"; return 1; }
  for f in "$1/$3"/bake/frame.*.h5; do cmp -s "$f" "$2/$3/bake/$(basename "$f")" || { echo "differs: $f"; ok=1; }; done
  return $ok
}
# ledger_balanced dir shot count: every frame's ledger sums to zero per axis; steps > 0; the largest axis is not 0
ledger_balanced() {
  local i f a h l s big=0
  for i in $(seq 1 "$3"); do
    f=$(printf "%s/%s/bake/frame.%04d.h5" "$1" "$2" "$i")
    s=$(h5num "$f" /diagnostics/coupling_steps)
    [ -n "$s" ] && awk -v s="$s" 'BEGIN{exit !(s > 0)}' || { echo "frame $i: coupling_steps '$s'"; return 1; }
    for a in x y z; do
      h=$(h5num "$f" /diagnostics/coupling_impulse_hair_$a); l=$(h5num "$f" /diagnostics/coupling_impulse_liquid_$a)
      awk -v h="$h" -v l="$l" 'BEGIN{ m = (h < 0 ? -h : h); n = (l < 0 ? -l : l); if (n > m) m = n
                                      d = h + l; if (d < 0) d = -d; exit !(h != "" && l != "" && d <= 1e-12 * m) }' \
        || { echo "frame $i axis $a: hair $h + fluid $l is not 0 to 1e-12"; return 1; }
      big=$(awk -v b="$big" -v h="$h" 'BEGIN{ if (h < 0) h = -h; print (h > b) ? h : b }')
    done
  done
  awk -v b="$big" 'BEGIN{exit !(b > 0)}' || { echo "the ledger is zero on every axis"; return 1; }
}
# impulse_sign dir shot frame axis sign: the hair's impulse over the frame along the axis has the sign (+1 or -1)
impulse_sign() {
  local f h
  f=$(printf "%s/%s/bake/frame.%04d.h5" "$1" "$2" "$3")
  h=$(h5num "$f" /diagnostics/coupling_impulse_hair_$4)
  awk -v h="$h" -v s="$5" 'BEGIN{exit !(h != "" && h * s > 0)}' || { echo "hair impulse $4 = $h"; return 1; }
}

for shot in fur_tank fur_wind; do
  scene="$ROOT/assets/scenes/$shot.json"
  o1="$WORK/$shot.j1"; o2="$WORK/$shot.j2"; o3="$WORK/$shot.resumed"
  "$BIN/bake" "$scene" -j 1 --frames 1-3 --out "$o1" -q >/dev/null 2>&1
  "$BIN/bake" "$scene" -j 2 --frames 1-3 --out "$o2" -q >/dev/null 2>&1
  check "$shot: a coupled bake on 1 and on 2 threads is bit-identical" same_frames "$o1" "$o2" "$shot" 3
  "$BIN/bake" "$scene" -j 2 --frames 1-2 --out "$o3" -q >/dev/null 2>&1
  "$BIN/bake" "$scene" -j 2 --frames 1-3 --out "$o3" --resume >"$WORK/$shot.resume.log" 2>&1
  check "$shot: the coupled bake resumes after frame 2" grep -q "resuming after frame 2" "$WORK/$shot.resume.log"
  check "$shot: a resumed coupled bake is bit-identical to an uninterrupted one" same_frames "$o2" "$o3" "$shot" 3
  check "$shot: coupled steps in every frame and the momentum ledger sums to zero per axis to 1e-12" \
    ledger_balanced "$o2" "$shot" 3
done
# The ball sweeps the fur through still water towards +x: the water pushes the hair back (−x). The wind blows
# towards +x past the held fur: it pushes the hair downwind (+x).
check "fur_tank: the liquid pushes the swept hair back (−x)" impulse_sign "$WORK/fur_tank.j2" fur_tank 3 x -1
check "fur_wind: the wind pushes the hair downwind (+x)" impulse_sign "$WORK/fur_wind.j2" fur_wind 3 x 1
