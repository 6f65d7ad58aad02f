# The render stage end to end: frame PNGs of the requested size, contact sheet, plots, camera-only changes
# re-render and nothing else, frame ranges sealed by --finish, bad input, and a killed render.
source "$(dirname "$0")/lib.sh"
scene=$(stage_scene small_dam.json)
sed -i 's/"render": { "camera": { "fov_deg": 40 } }/"render": { "resolution": [480, 270], "camera": { "eye": [0.75, 0.45, 0.65], "target": [0.2, 0.08, 0.1], "fov_deg": 40 } }/' "$scene"
rd="$DRENCH_OUT/small_dam/render"

png_size() { od -An -tu1 -j16 -N8 "$1" | awk '{printf "%dx%d", $1*16777216+$2*65536+$3*256+$4, $5*16777216+$6*65536+$7*256+$8}'; }
png_complete() { [ "$(tail -c 8 "$1" | head -c 4)" = IEND ]; }

out=$("$ROOT/pipeline.sh" --no-build "$scene" 2>&1); rc=$?
echo "$out" | tail -4
check "pipeline runs through render" test "$rc" -eq 0
check "12 frame PNGs" test "$(ls "$rd"/frame.*.png 2>/dev/null | wc -l)" -eq 12
check "frame PNGs have the scene's resolution" test "$(png_size "$rd/frame.0007.png")" = 480x270
check "contact sheet written" test -s "$rd/contact_sheet.png"
check "every PNG is complete" bash -c "for f in '$rd'/*.png; do [ \"\$(tail -c 8 \"\$f\" | head -c 4)\" = IEND ] || exit 1; done"
check "plots of the bake written" test "$(ls "$rd"/plots/*.png 2>/dev/null | wc -l)" -ge 3
check "render MANIFEST written" grep -q "^key $("$BIN/render" --print-key "$scene")" "$rd/MANIFEST"
check "frames are not all alike (the liquid moves)" bash -c "! cmp -s '$rd/frame.0001.png' '$rd/frame.0012.png'"
grep -o 'render: .*s/frame[^,]*' <<<"$out" | head -1

sed -i 's/"eye": \[0.75, 0.45, 0.65\]/"eye": [0.8, 0.5, 0.7]/' "$scene"
out=$("$ROOT/pipeline.sh" --no-build "$scene" 2>&1)
check "camera change: precompute, bake and mesh up to date" \
  bash -c "grep -q 'precompute: up to date' <<<'$out' && grep -q 'bake: up to date' <<<'$out' && grep -q 'mesh: up to date' <<<'$out'"
check "camera change: render runs" bash -c "grep -q 'render: running' <<<'$out' && grep -q 'pipeline: 1 stage(s) ran' <<<'$out'"

# bad input: nothing rendered, the previous images untouched
before=$(cat "$rd"/*.png | md5sum)
bad="$WORK/scenes/bad_res.json"
sed 's/"resolution": \[480, 270\]/"resolution": [0, 270]/' "$scene" > "$bad"
expect_exit "resolution 0 exits 2 naming the field" 2 "render.*resolution" "$BIN/render" "$bad"
bad="$WORK/scenes/bad_eye.json"
sed 's/"eye": \[0.8, 0.5, 0.7\]/"eye": [0.2, 0.08, 0.1]/' "$scene" > "$bad"
expect_exit "eye at the target exits 2 naming the camera" 2 "render.camera" "$BIN/render" "$bad"
check "bad input left the images untouched" test "$(cat "$rd"/*.png | md5sum)" = "$before"

# a camera looking away from everything renders background images, not an error
away="$WORK/scenes/away.json"
sed 's/"target": \[0.2, 0.08, 0.1\]/"target": [5, 3, 9]/' "$scene" > "$away"
expect_exit "camera looking at nothing renders" 0 "render:" "$BIN/render" "$away" --frames 1-2 -q

# frame ranges run apart (a farm's array), then --finish seals them; a range records its frames in the MANIFEST,
# and the range that completes the shot writes the contact sheet
rm -rf "$rd"
"$BIN/render" "$scene" --frames 1-6 -q 2>/dev/null
check "a frame range's MANIFEST claims its frames only, and there is no contact sheet" \
  bash -c "grep -qx 'frames 1-6' '$rd/MANIFEST' && [ ! -e '$rd/contact_sheet.png' ]"
expect_exit "--finish with frames missing exits 2" 2 "frame 7 has not been rendered" "$BIN/render" "$scene" --finish
"$BIN/render" "$scene" --frames 7-12 -q 2>/dev/null
check "the range that completes the shot claims it whole and writes the contact sheet" \
  bash -c "grep -qx 'frames 1-12' '$rd/MANIFEST' && [ -s '$rd/contact_sheet.png' ]"
expect_exit "--finish after every range" 0 "MANIFEST written" "$BIN/render" "$scene" --finish
check "--finish wrote the contact sheet and MANIFEST" test -s "$rd/contact_sheet.png" -a -s "$rd/MANIFEST"
expect_exit "render --plots" 0 "plots written" "$BIN/render" "$scene" --plots

# a killed render leaves no partial PNG under a final name; the next run clears its temporary files
rm -rf "$rd"
big="$WORK/scenes/big.json"
sed 's/"resolution": \[480, 270\]/"resolution": [1920, 1080], "samples": 4/' "$scene" > "$big"
"$BIN/render" "$big" -j 1 -q >/dev/null 2>&1 &
pid=$!
for _ in $(seq 200); do ls "$rd"/frame.*.png* >/dev/null 2>&1 && break; sleep 0.05; done
sleep 0.3
kill -9 "$pid" 2>/dev/null; wait "$pid" 2>/dev/null
check "killed render: every PNG under a final name is complete" \
  bash -c "for f in '$rd'/frame.*.png; do [ -e \"\$f\" ] || continue; [ \"\$(tail -c 8 \"\$f\" | head -c 4)\" = IEND ] || exit 1; done"
check "killed render: no MANIFEST" test ! -e "$rd/MANIFEST"
"$BIN/render" "$scene" --frames 1-1 -q 2>/dev/null
"$BIN/render" "$scene" -q 2>/dev/null
check "the next full run clears the killed run's temporary files" test -z "$(ls "$rd" | grep '\.tmp\.')"
