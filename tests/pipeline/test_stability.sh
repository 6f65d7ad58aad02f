# The stability watch (README "Stability watch"): a solver whose energy grows beyond the work done on it, or a liquid
# that collapses, is a warning naming the element, the frame and the fix, or with solver.on_instability "fail" exit 1
# after the frames before it; a frame too long for the solvers' substeps is refused as bad input.
source "$(dirname "$0")/lib.sh"
data="$ROOT/tests/data"
mkdir -p "$WORK/scenes"
frame_file() { echo "$DRENCH_OUT/$1/bake/frame.$(printf %04d "$2").h5"; }
nothing_written() { [ ! -e "$DRENCH_OUT" ] || [ -z "$(find "$DRENCH_OUT" -type f)" ]; }

# 1. MPM: symplectic Euler held to 30 substeps a frame where its wave limit asks for ~34: the energy grows from frame 3
#    (×4.9 by frame 4). Before the watch this baked with exit 0 and only the substep-cap warnings.
out=$("$BIN/bake" "$data/mpm_explicit_cap.json" 2>&1); rc=$?
check "mpm: an unstable bake still completes with on_instability warn" [ "$rc" -eq 0 ]
check "mpm: the warning names element, frame and the fix" bash -c "echo \"\$1\" | grep -Eq \
  \"warning: frame 3: mpm_solid 'jelly': the energy grew by .* raise solver.max_substeps\"" _ "$out"
sed 's/"max_substeps": 30 }/"max_substeps": 30, "on_instability": "fail" }/' "$data/mpm_explicit_cap.json" \
  > "$WORK/scenes/mpm_fail.json"
grep -q '"on_instability": "fail"' "$WORK/scenes/mpm_fail.json" || fail "mpm: fail scene" "sed did not apply"
rm -rf "$DRENCH_OUT"
expect_exit "mpm: on_instability fail stops with exit 1 naming element and frame" 1 \
  "error: frame 3: mpm_solid 'jelly': the energy grew .*solver.on_instability is \"fail\"" \
  "$BIN/bake" "$WORK/scenes/mpm_fail.json"
check "mpm: the frames before the failure are written" test -f "$(frame_file mpm_explicit_cap 2)"
check "mpm: the failing frame is not written" test ! -e "$(frame_file mpm_explicit_cap 3)"

# 2. Liquid: a dam break stepped once a frame at cfl 10 without volume correction piles its particles together: 27 %
#    of its volume gone by frame 4, half by frame 8 (with only the substep-cap warnings before the watch).
out=$("$BIN/bake" "$data/dam_collapse.json" 2>&1); rc=$?
check "liquid: a collapsing bake completes with on_instability warn" [ "$rc" -eq 0 ]
check "liquid: the volume warning names element, frame and the fix" bash -c "echo \"\$1\" | grep -Eq \
  \"warning: frame [0-9]+: liquid 'water': its particles fill [0-9]+ % of their volume.*collapsed.*lower solver.cfl\"" \
  _ "$out"
fill=$(h5dump -d /diagnostics/water/particle_volume -d /diagnostics/water/particle_volume_nominal \
  "$(frame_file dam_collapse 8)" 2>/dev/null | awk '/\(0\): [0-9]/{v[n++]=$2} END{if (n == 2) printf "%.3f", v[0] / v[1]}')
check "liquid: the frame cache's particle volume shows the collapse (fill $fill < 0.7)" \
  awk -v f="${fill:-1}" 'BEGIN{exit !(f < 0.7)}'
sed 's/"max_substeps": 1 }/"max_substeps": 1, "on_instability": "fail" }/' "$data/dam_collapse.json" > "$WORK/scenes/dam_fail.json"
rm -rf "$DRENCH_OUT"
expect_exit "liquid: on_instability fail stops with exit 1" 1 "error: frame [0-9]+: liquid 'water': .*collapsed" \
  "$BIN/bake" "$WORK/scenes/dam_fail.json"

# 3. A stable shot raises no alarm: the MPM drop of the golden test, and a dam break at its own substeps.
out=$("$BIN/bake" "$data/mpm_drop.json" 2>&1)
check "mpm_drop bakes without a stability warning" bash -c "! echo \"\$1\" | grep -q 'warning'" _ "$out"
out=$("$BIN/bake" "$data/dam_volume.json" --frames 1-24 2>&1)
check "dam_volume bakes without a stability warning" bash -c "! echo \"\$1\" | grep -q 'warning'" _ "$out"

# 4. A frame longer than max_substeps substeps of the solver's step as anything starts to fall (fps 0.001: 1000 s
#    frames, which collapsed 98 % of a dam break into one cell) is bad input: exit 2 naming shot.fps and
#    solver.max_substeps with the fix, and nothing written.
rm -rf "$DRENCH_OUT"
sed 's/"fps": 24/"fps": 0.001/' "$data/dam_volume.json" > "$WORK/scenes/dam_fps.json"
expect_exit "liquid: fps 0.001 is refused" 2 \
  "shot\.fps = 0\.001: a frame of 1000 s needs at least [0-9]+ substeps of liquid 'water'.*solver\.max_substeps is 32.*raise shot\.fps to at least" \
  "$BIN/bake" "$WORK/scenes/dam_fps.json"
sed 's/"fps": 24/"fps": 0.001/' "$data/mpm_drop.json" > "$WORK/scenes/mpm_fps.json"
expect_exit "mpm: fps 0.001 is refused" 2 "shot\.fps = 0\.001: .*the MPM solids.*raise shot\.fps" \
  "$BIN/bake" "$WORK/scenes/mpm_fps.json"
check "a refused frame length writes nothing" nothing_written

# 5. solver.on_instability takes warn or fail only.
sed 's/"max_substeps": 32 }/"max_substeps": 32, "on_instability": "stop" }/' "$data/dam_volume.json" \
  > "$WORK/scenes/bad_mode.json"
expect_exit "on_instability: an unknown value names the field and its choices" 2 \
  "solver\.on_instability.*(warn|fail)" "$BIN/bake" "$WORK/scenes/bad_mode.json"
check "on_instability: the bad value writes nothing" nothing_written
