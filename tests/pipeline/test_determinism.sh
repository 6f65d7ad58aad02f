# Determinism: two bakes with the same thread count give bit-identical frames; a bake killed with SIGKILL and
# resumed gives frames bit-identical to an uninterrupted bake; a killed bake leaves nothing a later stage trusts.
source "$(dirname "$0")/lib.sh"
scene="$ROOT/assets/scenes/small_dam.json"
a="$WORK/a"; b="$WORK/b"; c="$WORK/c"
"$BIN/bake" "$scene" -j 2 --out "$a" -q >/dev/null 2>&1
"$BIN/bake" "$scene" -j 2 --out "$b" -q >/dev/null 2>&1
same_frames() { local f ok=0; for f in "$1"/small_dam/bake/frame.*.h5; do cmp -s "$f" "$2/small_dam/bake/$(basename "$f")" || { echo "differs: $f"; ok=1; }; done
                [ "$(ls "$1"/small_dam/bake/frame.*.h5 | wc -l)" -eq 12 ] && return $ok; }
check "two bakes with 2 threads are bit-identical" same_frames "$a" "$b"
# every particle's own volume (m^3) next to its id: seeded at dx^3/per_cell (0.025^3/8 in small_dam), one per id
volumes_cached() {
  local f="$a/small_dam/bake/frame.0006.h5" n
  h5dump -a /water/volume/units "$f" | grep -q '"m^3"' || return 1
  n=$(h5 "$f" /water/id | wc -w)
  [ "$n" -gt 1000 ] && [ "$(h5 "$f" /water/volume | wc -w)" -eq "$n" ] || return 1
  h5 "$f" /water/volume | awk '{ for (i = 1; i <= NF; i++) if ($i != 0.025 * 0.025 * 0.025 / 8) exit 1 }' || return 1
  h5dump -a /diagnostics/water/killed_volume/units "$f" | grep -q '"m^3"' &&
    h5dump -a /diagnostics/water/emitted_volume/units "$f" | grep -q '"m^3"'
}
check "the frame cache holds /water/volume (m^3), one nominal volume per particle, and the frame's emitted and killed volumes" volumes_cached

"$BIN/bake" "$scene" -j 2 --out "$c" -q >/dev/null 2>&1 &
pid=$!
for _ in $(seq 1 600); do [ -f "$c/small_dam/bake/frame.0005.h5" ] && break; sleep 0.05; done
kill -9 $pid 2>/dev/null; wait $pid 2>/dev/null
check "a killed bake leaves no MANIFEST" test ! -f "$c/small_dam/bake/MANIFEST"
check "a killed bake leaves only complete frames" bash -c "for f in '$c'/small_dam/bake/frame.*.h5; do h5dump -A \"\$f\" >/dev/null 2>&1 || exit 1; done"
expect_exit "mesh refuses to run on an incomplete bake" 2 "has not been baked" "$BIN/mesh" "$scene" --out "$c"
"$BIN/bake" "$scene" -j 2 --out "$c" --resume >"$WORK/resume.log" 2>&1
check "resume continues from the checkpoint" grep -q "resuming after frame" "$WORK/resume.log"
check "killed and resumed bake is bit-identical to an uninterrupted one" same_frames "$a" "$c"
check "resumed bake writes its MANIFEST" test -f "$c/small_dam/bake/MANIFEST"

# MPM solids: a bake on 1 and on 2 threads, and one stopped after frame 3 and resumed, give bit-identical
# frames (the impact on the floor, with its Newton and CG solves, happens in frames 3-5).
mpm="$ROOT/tests/data/mpm_drop.json"
m1="$WORK/m1"; m2="$WORK/m2"; m3="$WORK/m3"
"$BIN/bake" "$mpm" -j 1 --frames 1-6 --out "$m1" -q >/dev/null 2>&1
"$BIN/bake" "$mpm" -j 2 --frames 1-6 --out "$m2" -q >/dev/null 2>&1
same_mpm_frames() { local f ok=0; for f in "$1"/mpm_drop/bake/frame.*.h5; do cmp -s "$f" "$2/mpm_drop/bake/$(basename "$f")" || { echo "differs: $f"; ok=1; }; done
                    [ "$(ls "$1"/mpm_drop/bake/frame.*.h5 | wc -l)" -eq 6 ] && return $ok; }
check "an MPM bake on 1 and on 2 threads is bit-identical" same_mpm_frames "$m1" "$m2"
"$BIN/bake" "$mpm" -j 2 --frames 1-3 --out "$m3" -q >/dev/null 2>&1
"$BIN/bake" "$mpm" -j 2 --frames 1-6 --out "$m3" --resume >"$WORK/mpm_resume.log" 2>&1
check "the MPM bake resumes after frame 3" grep -q "resuming after frame 3" "$WORK/mpm_resume.log"
check "a resumed MPM bake is bit-identical to an uninterrupted one" same_mpm_frames "$m2" "$m3"

# Hair: a bake on 1 and on 2 threads, and one stopped after frame 3 and resumed, give bit-identical frames
# (the checkpoint carries the reference directors, reference twists and multipliers the next step needs).
hair="$ROOT/tests/data/hair_small.json"
h1="$WORK/h1"; h2="$WORK/h2"; h3="$WORK/h3"
"$BIN/bake" "$hair" -j 1 --out "$h1" -q >/dev/null 2>&1
"$BIN/bake" "$hair" -j 2 --out "$h2" -q >/dev/null 2>&1
same_hair_frames() { local f ok=0; for f in "$1"/hair_small/bake/frame.*.h5; do cmp -s "$f" "$2/hair_small/bake/$(basename "$f")" || { echo "differs: $f"; ok=1; }; done
                     [ "$(ls "$1"/hair_small/bake/frame.*.h5 | wc -l)" -eq 8 ] && return $ok; }
check "a hair bake on 1 and on 2 threads is bit-identical" same_hair_frames "$h1" "$h2"
"$BIN/bake" "$hair" -j 2 --frames 1-3 --out "$h3" -q >/dev/null 2>&1
"$BIN/bake" "$hair" -j 2 --out "$h3" --resume >"$WORK/hair_resume.log" 2>&1
check "the hair bake resumes after frame 3" grep -q "resuming after frame 3" "$WORK/hair_resume.log"
check "a resumed hair bake is bit-identical to an uninterrupted one" same_hair_frames "$h2" "$h3"
# Heavy hair pressing on the shaken head, with frames whose hair steps the strands' speed cuts (HairSolver.cfl):
# stopped after frame 7, when 7-8 vertices press on the head, and resumed.
heavy="$ROOT/tests/data/hair_heavy_shake.json"
k1="$WORK/k1"; k2="$WORK/k2"
"$BIN/bake" "$heavy" -j 2 --out "$k1" -q >/dev/null 2>&1
"$BIN/bake" "$heavy" -j 2 --frames 1-7 --out "$k2" -q >/dev/null 2>&1
"$BIN/bake" "$heavy" -j 2 --out "$k2" --resume >"$WORK/heavy_resume.log" 2>&1
same_heavy_frames() { local f ok=0; for f in "$1"/hair_heavy_shake/bake/frame.*.h5; do cmp -s "$f" "$2/hair_heavy_shake/bake/$(basename "$f")" || { echo "differs: $f"; ok=1; }; done
                      [ "$(ls "$1"/hair_heavy_shake/bake/frame.*.h5 | wc -l)" -eq 10 ] && return $ok; }
check "the heavy hair bake resumes after frame 7 with vertices pressing on the head" bash -c "
  grep -q 'resuming after frame 7' '$WORK/heavy_resume.log' &&
  h5dump -d /diagnostics/hair_collider_contacts '$k2/hair_heavy_shake/bake/frame.0007.h5' | grep -Eq '\(0\): [1-9]'"
check "a resumed bake of hair pressing on a collider with friction is bit-identical" same_heavy_frames "$k1" "$k2"

# Boundary-element bodies: a spinning body in a moving frame and one in a fixed frame (whose displacement carries
# its fall through the history sums), sharing one matrix set; a bake on 1 and on 2 threads, and one stopped after
# frame 2 and resumed (the checkpoint carries each body's history window, frame and step count), give
# bit-identical frames.
bem="$ROOT/tests/data/bem_pair.json"
b1="$WORK/b1"; b2="$WORK/b2"; b3="$WORK/b3"
"$BIN/precompute" "$bem" -j 2 -q >/dev/null 2>&1
"$BIN/bake" "$bem" -j 1 --out "$b1" -q >/dev/null 2>&1
"$BIN/bake" "$bem" -j 2 --out "$b2" -q >/dev/null 2>&1
same_bem_frames() { local f ok=0; for f in "$1"/bem_pair/bake/frame.*.h5; do cmp -s "$f" "$2/bem_pair/bake/$(basename "$f")" || { echo "differs: $f"; ok=1; }; done
                    [ "$(ls "$1"/bem_pair/bake/frame.*.h5 | wc -l)" -eq 4 ] && return $ok; }
check "a BEM bake on 1 and on 2 threads is bit-identical" same_bem_frames "$b1" "$b2"
"$BIN/bake" "$bem" -j 2 --frames 1-2 --out "$b3" -q >/dev/null 2>&1
"$BIN/bake" "$bem" -j 2 --out "$b3" --resume >"$WORK/bem_resume.log" 2>&1
check "the BEM bake resumes after frame 2" grep -q "resuming after frame 2" "$WORK/bem_resume.log"
check "a resumed BEM bake is bit-identical to an uninterrupted one" same_bem_frames "$b2" "$b3"
h5_first() { h5dump -d "$2" "$1" 2>/dev/null | awk '/\(0\): [-0-9]/{print $2; exit}'; }
deformed() { awk -v u="$(h5_first "$b3/bem_pair/bake/frame.0004.h5" /diagnostics/fixed/max_displacement)" 'BEGIN { exit !(u > 1e-3) }'; }
check "the fixed-frame body deforms, so the resumed history matters" deformed
check "the checkpoint records each body's step count (40 after frame 4)" \
  test "$(h5_first "$b3/bem_pair/bake/checkpoint.h5" /fixed/steps)" = 40
