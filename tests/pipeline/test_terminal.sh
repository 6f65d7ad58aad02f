# What a person at a terminal sees, and what a farm manager reads: the progress bar redrawn in place on a tty,
# ALF_PROGRESS only off a tty (or when asked), -q, peak memory, the defaults a bake applied (report.json, -v),
# --list-components' layout, pipeline.sh --version, --preview and its argument checks when everything is up to date,
# and the preview renderer's frame-to-frame consistency and plots.
source "$(dirname "$0")/lib.sh"
scene="$ROOT/assets/scenes/small_dam.json"
PNGSTAT="$ROOT/build/tests/pngstat"

# on_tty COLS COMMAND...: runs COMMAND on a pseudo-terminal COLS columns wide (stdout and stderr both the tty),
# without CI set, and prints what the terminal received
on_tty() {
  local cols="$1"; shift
  local cmd; printf -v cmd '%q ' "$@"
  script -qfec "stty cols $cols rows 24; env -u CI $cmd" /dev/null
}

# ---- progress on a terminal: one bar redrawn in place, never wider than the terminal, no ALF lines ----------------
tty_out=$(on_tty 80 "$BIN/bake" "$scene" --frames 1-3 -j 1 --out "$WORK/tty")
bars=$(printf '%s' "$tty_out" | tr '\r' '\n' | grep -c '^bake \[')
widest=$(printf '%s' "$tty_out" | tr '\r' '\n' | sed 's/\x1b\[K//g' | grep '^bake \[' | awk '{ if (length($0) > w) w = length($0) } END { print w + 0 }')
check "tty: the bar is redrawn once per frame" test "$bars" -eq 3
check "tty: the bar fits an 80-column terminal (widest $widest)" test "$widest" -le 79
check "tty: the bar gives ETA and peak RSS" bash -c "grep -q 'ETA .* RSS [0-9]' <<<'$(printf '%s' "$tty_out" | tr '\r' '\n' | grep '^bake \[' | head -1)'"
check "tty: no ALF_PROGRESS lines on a terminal" bash -c "! grep -q ALF_PROGRESS <<<\"\$1\"" _ "$tty_out"
asked=$(DRENCH_ALF_PROGRESS=1 on_tty 80 "$BIN/bake" "$scene" --frames 1-2 -j 1 --out "$WORK/tty")
check "tty: ALF_PROGRESS lines when DRENCH_ALF_PROGRESS=1" bash -c "grep -q 'ALF_PROGRESS 100%' <<<\"\$1\"" _ "$asked"
quiet=$(on_tty 80 "$BIN/bake" "$scene" --frames 1-2 -j 1 --out "$WORK/tty" -q)
check "tty: -q draws no bar" bash -c "! grep -q 'bake \[' <<<\"\$1\"" _ "$quiet"

# ---- progress off a terminal: a line per frame with peak RSS on stderr, ALF_PROGRESS on stdout ----------------------
"$BIN/bake" "$scene" --frames 1-3 -j 1 --out "$WORK/pipe" >"$WORK/stdout" 2>"$WORK/stderr"
check "pipe: a progress line per frame with ETA and peak RSS" test "$(grep -c '^bake [0-9]/3 .*ETA .*peak RSS [0-9]' "$WORK/stderr")" -eq 3
check "pipe: ALF_PROGRESS lines on stdout" grep -q '^ALF_PROGRESS 100%' "$WORK/stdout"
check "pipe: the summary line gives the peak RSS" grep -q '^bake: .*peak RSS [0-9]' "$WORK/stderr"
"$BIN/bake" "$scene" --frames 1-3 -j 1 --out "$WORK/pipe" -q >"$WORK/stdout" 2>"$WORK/stderr"
check "pipe: -q prints no progress lines" bash -c "! grep -q '^bake [0-9]/3' '$WORK/stderr'"
check "pipe: -q keeps ALF_PROGRESS for the farm manager" grep -q '^ALF_PROGRESS 100%' "$WORK/stdout"
DRENCH_ALF_PROGRESS=0 "$BIN/bake" "$scene" --frames 1-1 -j 1 --out "$WORK/pipe" -q >"$WORK/stdout" 2>/dev/null
check "pipe: DRENCH_ALF_PROGRESS=0 silences ALF_PROGRESS" test ! -s "$WORK/stdout"
report="$WORK/pipe/small_dam/bake/report.json"
check "report.json: peak RSS in bytes" python3 -c "
import json, sys; r = json.load(open(sys.argv[1])); sys.exit(0 if r['peak_rss_bytes'] > 1 << 20 else 1)" "$report"

# ---- defaults a bake applied: report.json per element and section, -v -------------------------------------------
check "report.json: the defaults each element took, and only those" python3 -c "
import json, sys
d = json.load(open(sys.argv[1]))['defaults_applied']
w, b, solver = d['elements']['water'], d['elements']['block'], d['sections']['solver']
ok = (w['LiquidMaterial'] == {'density': 1000}            # viscosity is written
      and w['Domain'] == {'wall_boundary': 'slip'}          # box and voxel_size are written
      and w['Transfer']['scheme'] == 'apic' and 'flip_blend' not in w['Transfer']
      and w['LiquidSource'] == {'velocity': [0, 0, 0]}      # box written, mesh unset (no default)
      and 'Emitter' not in w and 'KillBox' not in w         # absent: no emitter, no kill box
      and b['Collider'] == {'friction': 0, 'boundary': 'slip', 'thickness': 0}
      and b['Transform'] == {'rotate_deg': [0, 0, 0]} and 'Motion' not in b
      and solver['pressure_tolerance'] == 1e-06 and 'cfl' not in solver)
sys.exit(0 if ok else 1)" "$report"
"$BIN/bake" "$scene" --frames 1-1 -j 1 --out "$WORK/pipe" -v >/dev/null 2>"$WORK/stderr"
check "-v logs the defaults of each element" grep -q 'water (liquid): defaults applied: .*LiquidMaterial.density = 1000 kg/m^3' "$WORK/stderr"
check "-v logs the defaults of the solver section" grep -q 'solver: defaults applied: .*pressure_tolerance = 1e-06' "$WORK/stderr"
expect_exit "-q and -v together exit 2" 2 "contradict" "$BIN/bake" "$scene" -q -v

# ---- --list-components: within 100 columns, aligned, required components marked ----------------------------------
"$BIN/bake" --list-components >"$WORK/ref.txt"
check "list-components: no line beyond 100 columns" test "$(awk 'length($0) > 100' "$WORK/ref.txt" | wc -l)" -eq 0
# every field row starts its type, unit, default and range columns where the header line does
check "list-components: field rows aligned under the header" awk '
  /^    field +type +unit +default +range$/ { h = $0; t = index(h, "type"); u = index(h, "unit"); d = index(h, "default"); r = index(h, "range"); next }
  h && /^    [a-z_]+  / { rows++
    for (k = 1; k <= 4; k++) { c = k == 1 ? t : k == 2 ? u : k == 3 ? d : r
      if (substr($0, c - 1, 1) != " " || substr($0, c, 1) == " ") bad++ } }
  END { exit !(rows > 100 && bad == 0) }' "$WORK/ref.txt"
check "list-components: required components marked where they are described" bash -c \
  "grep -q '^  Domain (required): ' '$WORK/ref.txt' && grep -q '^  MpmShape (required): ' '$WORK/ref.txt' && grep -q '^  LiquidMaterial: ' '$WORK/ref.txt'"

# ---- pipeline.sh --version, and its checks of -j and --frames when every stage is up to date ---------------------
expect_exit "pipeline.sh --version" 0 "^pipeline.sh \(drench\) [0-9]+\.[0-9]+" "$ROOT/pipeline.sh" --version
mkdir -p "$WORK/scenes"
spread="$WORK/scenes/spread.json"
cat >"$spread" <<'EOF'
{
  "shot": { "name": "spread", "fps": 24, "frames": [1, 12] },
  "solver": { "cfl": 2.0, "max_substeps": 32 },
  "elements": [
    { "name": "water", "type": "liquid",
      "components": {
        "Domain": { "box": [[0, 0, 0], [0.8, 0.2, 0.2]], "voxel_size": 0.025 },
        "LiquidSource": { "box": [[0, 0, 0], [0.1, 0.15, 0.2]] } } }
  ],
  "render": { "resolution": [320, 180], "samples": 2,
              "camera": { "eye": [0.4, 0.5, 0.9], "target": [0.4, 0.05, 0.1], "fov_deg": 50 } }
}
EOF
"$ROOT/pipeline.sh" --no-build "$spread" -j 2 --no-plots >"$WORK/pipeline.log" 2>&1
check "a spreading dam runs through render" grep -q 'pipeline: 4 stage(s) ran' "$WORK/pipeline.log"
expect_exit "up to date: -j 0 exits 2" 2 "-j '0' must be a thread count" "$ROOT/pipeline.sh" --no-build "$spread" -j 0
expect_exit "up to date: -j x exits 2" 2 "-j 'x' must be a thread count" "$ROOT/pipeline.sh" --no-build "$spread" -j x
expect_exit "up to date: --frames outside the shot exits 2" 2 "outside the shot's frames 1-12" \
  "$ROOT/pipeline.sh" --no-build "$spread" --frames 1-400
expect_exit "up to date: --frames not a range exits 2" 2 "not a range" "$ROOT/pipeline.sh" --no-build "$spread" --frames 3
expect_exit "up to date: valid options still pass" 0 "pipeline: 0 stage\(s\) ran" "$ROOT/pipeline.sh" --no-build "$spread" -j 2

# ---- the preview renderer: what does not move stays the same from frame to frame ---------------------------------
rd="$DRENCH_OUT/spread/render"
far_ground() { "$PNGSTAT" "$1" 0 0 320 40; }
check "the ground far from the spreading water is the same in frames 1 and 12" \
  test "$(far_ground "$rd/frame.0001.png")" = "$(far_ground "$rd/frame.0012.png")"
check "the progress has the liquid's volume as its particles carry it (the seeded 0.1 x 0.15 x 0.2 m)" python3 -c "
import json, sys
v = [json.loads(l)['liquid_particle_volume'] for l in open(sys.argv[1])]
sys.exit(0 if len(v) == 12 and all(abs(x - 0.003) < 1e-9 for x in v) else 1)" "$DRENCH_OUT/spread/bake/progress.jsonl"

# ---- plots: no liquid plot without liquid, a colour per phase ----------------------------------------------------
plt="$WORK/scenes/plt.json"
cat >"$plt" <<'EOF'
{ "shot": { "name": "plt", "frames": [1, 6] },
  "elements": [ { "name": "jelly", "type": "mpm_solid", "components": {
      "Domain": { "box": [[0, 0, 0], [0.2, 0.2, 0.2]], "voxel_size": 0.02 },
      "MpmShape": { "box": [[0.05, 0.05, 0.05], [0.15, 0.15, 0.15]] } } } ] }
EOF
mkdir -p "$DRENCH_OUT/plt/bake"
# lines as a bake without liquid writes them (its liquid keys are zero), with twelve phases that took time
python3 -c "
import json
names = ['p2g', 'pressure', 'g2p', 'advect', 'other', 'mpm_transfer', 'mpm_solve', 'hair', 'bem_history', 'bem_solve', 'bem_trial', 'io']
for fr in range(1, 7):
    sec = {n: 0.01 * (i + 1) + 0.001 * fr for i, n in enumerate(names)}
    sec['frame'] = sum(sec.values())
    print(json.dumps({'frame': fr, 'substeps': 3, 'particles': 0, 'pressure_iterations_max': 0, 'pressure_iterations_total': 0,
                      'pressure_not_converged': 0, 'liquid_volume': 0, 'volume_drift': 0, 'kinetic_energy': 0.0,
                      'mpm_particles': 64, 'mpm_newton_iterations': 3, 'seconds': sec}))" >"$DRENCH_OUT/plt/bake/progress.jsonl"
"$BIN/render" "$plt" --plots >/dev/null 2>&1
pd="$DRENCH_OUT/plt/render/plots"
check "plots: a scene without liquid has no liquid volume plot" test -s "$pd/seconds_per_frame.png" -a ! -e "$pd/volume_drift.png"
# the key's colour boxes (right of the graph): one flat colour per phase
keys=$("$PNGSTAT" "$pd/seconds_per_frame.png" 800 40 840 240 60 | awk '{print $6}')
check "plots: twelve phases, twelve colours in the key ($keys)" test "$keys" -eq 12

# ---- pipeline.sh --preview: the scene's initial state in one PNG, nothing baked ------------------------------------
pv="$WORK/preview"
out=$(DRENCH_OUT="$pv" "$ROOT/pipeline.sh" --no-build --preview "$scene" -j 2 2>&1); rc=$?
check "--preview exits 0 and says where the image is" bash -c "[ $rc -eq 0 ] && grep -q 'preview.png' <<<\"\$1\"" _ "$out"
check "--preview writes out/<shot>/preview.png and nothing else" test "$(cd "$pv" && find . -type f)" = "./small_dam/preview.png"
check "--preview image has the scene's resolution" test "$(od -An -tu1 -j16 -N8 "$pv/small_dam/preview.png" | awk '{print $3*256+$4, $7*256+$8}')" = "960 540"
# the liquid source is drawn: without it the image differs where the water stands
nosrc="$WORK/scenes/nosource.json" # beside a copy of the meshes, which the scene names relative to itself
sed 's/"LiquidSource": { "box": \[\[0, 0, 0\], \[0.15, 0.2, 0.2\]\] },//' "$(stage_scene small_dam.json)" >"$nosrc"
DRENCH_OUT="$WORK/preview2" "$BIN/render" "$nosrc" --preview -q 2>/dev/null
check "--preview draws the liquid source" bash -c "[ -s '$WORK/preview2/small_dam/preview.png' ] && [ -s '$pv/small_dam/preview.png' ] &&
  ! cmp -s '$pv/small_dam/preview.png' '$WORK/preview2/small_dam/preview.png'"
for s in hair_shake jelly_drop dragging_test; do
  expect_exit "--preview of $s (grooms, MPM and BEM bodies, moving colliders)" 0 "preview of the scene's initial state" \
    env DRENCH_OUT="$WORK/preview3" "$BIN/render" "$ROOT/assets/scenes/$s.json" --preview
done
expect_exit "--preview takes no --frames" 2 "takes none of" "$ROOT/pipeline.sh" --no-build --preview "$scene" --frames 1-2
