# Integrity of the caches end to end: a full disk fails with exit 1 (never a crash); damaged, foreign or edited
# frames, checkpoints and precompute caches are refused with one exit code, naming the file and what to rerun;
# bake --resume checks the frames before its checkpoint; pipeline.sh reruns from the first bad frame, resumes a
# stopped bake and keeps partial bakes, meshes and renders; nothing is written before the input is known good;
# failures name element, file and frame. Every corruption is made here, on copies.
source "$(dirname "$0")/lib.sh"
scene=$(stage_scene small_dam.json)
# a small render, so that the pipeline checks stay quick
sed -i 's/"render": { "camera": { "fov_deg": 40 } }/"render": { "resolution": [160, 90], "camera": { "fov_deg": 40 } }/' "$scene"
grep -q '"resolution": \[160, 90\]' "$scene" || fail "scene setup" "the render resolution was not set"
B="$DRENCH_OUT/small_dam/bake"; M="$DRENCH_OUT/small_dam/mesh"; R="$DRENCH_OUT/small_dam/render"
pipeline() { "$ROOT/pipeline.sh" --no-build --no-plots "$scene" "$@" 2>&1; }
# offset_of FILE DATASET: where a contiguous dataset's bytes start in the file (h5dump -p)
offset_of() { h5dump -p -H -d "$2" "$1" | awk '$1=="OFFSET"{print $2; exit}'; }
# flip_byte FILE OFFSET: inverts the lowest bit of one byte in place
flip_byte() {
  local b; b=$(od -An -tu1 -j "$2" -N1 "$1" | tr -d ' ')
  printf "$(printf '\\%03o' $((b ^ 1)))" | dd of="$1" bs=1 seek="$2" conv=notrunc status=none
}
inode() { stat -c %i "$1"; }
# said CODE TEXT PATTERN...: the exit code was CODE and TEXT matches every pattern (grep -E); says what is missing
said() {
  local code=$1 text=$2 p; shift 2
  [ "$rc" -eq "$code" ] || { echo "exit $rc, expected $code: $(head -c 400 <<< "$text")"; return 1; }
  for p in "$@"; do grep -Eq -- "$p" <<< "$text" || { echo "lacks /$p/: $(head -c 600 <<< "$text")"; return 1; }; done
}
not_said() { ! grep -Eq -- "$1" <<< "$2"; }
fresh() { rm -rf "$DRENCH_OUT"; }

# ---- 1. full disk: whatever file the space runs out in, and wherever in it, exit 1 and nothing left behind ----------
# The tmpfs sizes bracket one frame file: the failure lands in the frame's data, in its last bytes (the ones HDF5 wrote
# on closing, which crashed in HDF5's exit-time cleanup with exit 139), or in the checkpoint after it.
"$BIN/bake" "$scene" -j 2 --frames 1-1 --out "$WORK/size" -q >/dev/null 2>&1
frame_kb=$(( $(stat -c %s "$WORK/size/small_dam/bake/frame.0001.h5") / 1024 ))
tmpfs="$WORK/tmpfs"; mkdir -p "$tmpfs"
if mount -t tmpfs -o size=64k tmpfs "$tmpfs" 2>/dev/null; then
  umount "$tmpfs"
  codes=""; left=""
  for kb in $(seq $((frame_kb - 8)) 4 $((frame_kb + 12))); do
    for mode in "" --sync-writes; do
      mount -t tmpfs -o size=${kb}k tmpfs "$tmpfs"
      "$BIN/bake" "$scene" -j 2 --out "$tmpfs/out" -q $mode >"$WORK/full.log" 2>&1; rc=$?
      codes+=" $rc"
      grep -q 'frame.0001.h5\|checkpoint.h5\|frame.0002.h5' "$WORK/full.log" || codes+="(no file named)"
      [ -n "$(find "$tmpfs/out" -name '*.tmp.*' -o -name MANIFEST 2>/dev/null)" ] && left+=" ${kb}k$mode"
      umount "$tmpfs"
    done
  done
  check "a full disk ends every bake with exit 1 naming the file, never a crash (exit codes:$codes)" \
    bash -c "[ -z \"\$(echo '$codes' | tr ' ' '\n' | grep -v '^1\$' | grep .)\" ]"
  check "a full disk leaves no temporary file and no MANIFEST${left:+ (left:$left)}" test -z "$left"
else
  echo "SKIP full disk on a small tmpfs (cannot mount tmpfs here: not root or no CAP_SYS_ADMIN)"
fi

# ---- 2. damaged or foreign data ----------------------------------------------------------------------------------------
"$BIN/bake" "$scene" -j 2 -q >/dev/null 2>&1
cp -a "$B" "$WORK/good_bake"
restore() { rm -rf "$B" && cp -a "$WORK/good_bake" "$B"; }
nothing_meshed() { [ ! -e "$M" ] || [ -z "$(ls "$M")" ]; }

cp "$B/frame.0005.h5" "$B/frame.0006.h5"
expect_exit "a frame copied over the next is refused (its frame attribute disagrees)" 2 \
  "frame.0006.h5: error: frame 6 cannot be meshed: the file holds frame 5" "$BIN/mesh" "$scene" -q
check "mesh wrote nothing for it" nothing_meshed
restore

off=$(offset_of "$B/frame.0003.h5" /water/affine)
flip_byte "$B/frame.0003.h5" $((off + 1000))
expect_exit "one bit flipped in a dataset mesh does not read is found" 2 \
  "frame.0003.h5: error: frame 3 cannot be meshed: dataset /water/affine does not match its checksum.*bake it again" \
  "$BIN/mesh" "$scene" -q
check "mesh wrote nothing for it" nothing_meshed
expect_exit "bake --verify names the first bad frame and the frames before it" 2 \
  "frame.0003.h5: error: .*/water/affine.*frames 1-2 before it are good" "$BIN/bake" "$scene" --verify
check "bake --verify prints what pipeline.sh reads" bash -c \
  "[ \"\$('$BIN/bake' '$scene' --verify 2>/dev/null | tr '\n' ' ')\" = 'shot 1 12 good_through 2 checkpoint 12 ' ]"
restore

"$BIN/bake" "$scene" -j 2 --frames 1-6 -q >/dev/null 2>&1 # a checkpoint mid-shot, to resume from
off=$(offset_of "$B/checkpoint.h5" /water/velocity)
flip_byte "$B/checkpoint.h5" $((off + 4000))
out=$("$BIN/bake" "$scene" -j 2 --resume -q 2>&1); rc=$?
check "one bit flipped in the checkpoint stops --resume (exit 2) naming it, the element and the fix" \
  said 2 "$out" "checkpoint.h5: error: the checkpoint after frame 6 is damaged \(liquid 'water'" \
  "/water/velocity does not match its checksum" "without --resume"
check "and the advice is not about the time step" not_said cfl "$out"
restore

# frame corruption gets one exit code whatever HDF5 makes of it: a truncated file, a damaged compressed chunk (the
# zero affine matrices of a FLIP liquid are the one deflated dataset), a missing file
flip="$WORK/scenes/flip_dam.json"
sed 's/"LiquidMaterial": { "viscosity": 0.001 } }/"LiquidMaterial": { "viscosity": 0.001 }, "Transfer": { "scheme": "flip" } }/; s/"name": "small_dam"/"name": "flip_dam"/' "$scene" > "$flip"
"$BIN/bake" "$flip" -j 2 --frames 1-3 -q >/dev/null 2>&1
FB="$DRENCH_OUT/flip_dam/bake"
head -c 3000 "$FB/frame.0001.h5" > "$WORK/truncated.h5" && mv "$WORK/truncated.h5" "$FB/frame.0001.h5"
expect_exit "a truncated frame: exit 2" 2 "frame.0001.h5: error: frame 1 cannot be meshed" "$BIN/mesh" "$flip" --frames 1-1 -q
# the deflated chunk: the one zlib stream (78 01) outside every contiguous dataset's bytes
f2="$FB/frame.0002.h5"
h5dump -p -H "$f2" | awk '/CONTIGUOUS/{c=1} c&&$1=="SIZE"{s=$2} c&&$1=="OFFSET"{print $2, $2+s; c=0}' > "$WORK/ranges"
chunk=""
for p in $(grep -obUaP '\x78\x01' "$f2" | cut -d: -f1); do
  awk -v p="$p" '{if (p >= $1 && p < $2) inside = 1} END {exit inside}' "$WORK/ranges" && { chunk=$p; break; }
done
if [ -n "$chunk" ]; then
  for k in 4 5 6 7 8 9 10 11; do flip_byte "$f2" $((chunk + k)); done
  expect_exit "a frame whose compressed chunk HDF5 cannot decode: exit 2 as well" 2 \
    "frame.0002.h5: error: frame 2 cannot be meshed: .*(cannot read dataset /water/affine|/water/affine does not match)" \
    "$BIN/mesh" "$flip" --frames 2-2 -q
else
  fail "a frame whose compressed chunk HDF5 cannot decode" "no deflated chunk found in $f2"
fi
rm "$FB/frame.0003.h5"
expect_exit "a missing frame: exit 2" 2 "frame.0003.h5: error: frame 3 cannot be meshed: frame 3 has not been baked" \
  "$BIN/mesh" "$flip" --frames 3-3 -q

# an edited value in an uncompressed precompute cache (repacked contiguous, one value changed in place)
bem="$ROOT/tests/data/bem_small.json"
"$BIN/precompute" "$bem" -q >/dev/null 2>&1
cf=$(ls "$DRENCH_CACHE"/bem/*.h5)
h5repack -l CONTI "$cf" "$WORK/repacked.h5" && mv "$WORK/repacked.h5" "$cf"
out=$("$BIN/precompute" "$bem" 2>&1); rc=$?
check "a repacked (uncompressed) cache whose values are intact is a cache hit" said 0 "$out" "1 hit"
flip_byte "$cf" "$(offset_of "$cf" /body/volume)"
out=$("$BIN/bake" "$bem" -q 2>&1); rc=$?
check "bake refuses an edited BEM cache value (exit 2), naming the file and dataset, and asks for precompute" \
  said 2 "$out" "$(basename "$cf"): error: jelly: its precomputed BEM matrices cannot be used" \
  "/body/volume does not match its checksum" "run precompute"
check "bake does not say it will recompute it" not_said "will be recomputed" "$out"
out=$("$BIN/precompute" "$bem" 2>&1); rc=$?
check "precompute recomputes it and says so" said 0 "$out" \
  "/body/volume does not match its checksum.*; it will be recomputed" "1 computed"

# ---- 3. resume and pipeline.sh -----------------------------------------------------------------------------------------
fresh
"$BIN/precompute" "$scene" -q 2>/dev/null
"$BIN/bake" "$scene" -j 2 --frames 1-6 -q >/dev/null 2>&1
check "a partial bake records its frames in the MANIFEST" grep -qx 'frames 1-6' "$B/MANIFEST"
rm "$B/frame.0003.h5"
out=$("$BIN/bake" "$scene" -j 2 --resume -q 2>&1); rc=$?
check "bake --resume with a frame before its checkpoint missing exits 2 naming it" said 2 "$out" \
  "frame.0003.h5: error: bake --resume: the checkpoint continues after frame 6, but frame 3 is not usable"
check "and leaves no MANIFEST claiming the frames" test ! -f "$B/MANIFEST"
out=$(pipeline); rc=$?
check "pipeline.sh bakes again from the first frame when a frame before the checkpoint is missing" said 0 "$out" \
  "bake: running \(frames 3-12 are not baked yet; baking again from frame 1"
out=$(pipeline); rc=$?
check "and the next run has nothing to do (no loop between bake and mesh)" said 0 "$out" "pipeline: 0 stage\(s\) ran"

ino=$(inode "$M/water.0004.obj"); ino_r=$(inode "$R/frame.0004.png")
cp "$B/frame.0007.h5" "$B/frame.0008.h5"
out=$(pipeline); rc=$?
check "pipeline.sh finds a damaged frame and reruns from it: bake, then mesh and render of frames 8-12 only" \
  said 0 "$out" "frame.0008.h5: error: the file holds frame 7" "bake: running \(frame 8 is missing or damaged" \
  "mesh: running \(frames 8-12 to do \(frames 1-7 kept\)\)" "render: running \(frames 8-12 to do \(frames 1-7 kept\)\)"
check "meshes and images of the good frames are kept" test "$(inode "$M/water.0004.obj")" = "$ino" -a "$(inode "$R/frame.0004.png")" = "$ino_r"
check "the frames are good again" "$BIN/bake" "$scene" --verify
# a bit flipped in a frame's data: a run with nothing to do reads no frame data (bake --quick-checks the files); a
# run whose later stages read the frames checks them whole first and bakes from the damaged one
off=$(offset_of "$B/frame.0010.h5" /water/position)
flip_byte "$B/frame.0010.h5" $((off + 5000))
out=$(pipeline); rc=$?
check "with every stage complete, a bit flipped in frame 10 is left for the stages that read it" said 0 "$out" \
  "pipeline: 0 stage\(s\) ran"
out=$(pipeline --from mesh); rc=$?
check "a run that meshes finds it first and bakes again from frame 10" said 0 "$out" \
  "frame.0010.h5: error: dataset /water/position does not match its checksum" \
  "bake: running \(frame 10 is missing or damaged; continuing after frame 9|bake: running \(frame 10 is missing or damaged; baking again"
check "the frames are good after it" "$BIN/bake" "$scene" --verify

# a stopped bake (no MANIFEST, a good checkpoint) is resumed by pipeline.sh, the frames before it untouched
fresh
"$BIN/precompute" "$scene" -q 2>/dev/null
"$BIN/bake" "$scene" -j 2 --frames 1-5 -q >/dev/null 2>&1
rm "$B/MANIFEST"
ino=$(inode "$B/frame.0003.h5")
out=$(pipeline --resume); rc=$?
check "pipeline.sh resumes a stopped bake by itself (and takes --resume)" said 0 "$out" \
  "bake: running \(frames 6-12 are not baked yet; continuing after frame 5 \(--resume\)\)"
check "the frames before the checkpoint are not baked again" test "$(inode "$B/frame.0003.h5")" = "$ino"
check "the resumed frames equal an uninterrupted bake's" bash -c \
  "for f in '$WORK'/good_bake/frame.*.h5; do cmp -s \"\$f\" '$B'/\$(basename \"\$f\") || exit 1; done"

# partial bakes: --frames 1-4 twice does the work once; --frames 1-8 continues from frame 4 and keeps 1-4's outputs
fresh
pipeline --frames 1-4 >/dev/null
out=$(pipeline --frames 1-4); rc=$?
check "--frames 1-4 twice: the second run has nothing to do" said 0 "$out" "pipeline: 0 stage\(s\) ran"
ino_b=$(inode "$B/frame.0002.h5"); ino_m=$(inode "$M/water.0002.obj"); ino_r=$(inode "$R/frame.0002.png")
out=$(pipeline --frames 1-8); rc=$?
check "--frames 1-8 after 1-4 resumes the bake after frame 4 and meshes and renders frames 5-8 only" said 0 "$out" \
  "continuing after frame 4 \(--resume\)" "mesh: running \(frames 5-8 to do" "render: running \(frames 5-8 to do"
check "frames 1-4's frame caches, meshes and images are kept" test "$(inode "$B/frame.0002.h5")" = "$ino_b" -a \
  "$(inode "$M/water.0002.obj")" = "$ino_m" -a "$(inode "$R/frame.0002.png")" = "$ino_r"
check "the MANIFESTs record frames 1-8" bash -c "grep -qx 'frames 1-8' '$B/MANIFEST' && grep -qx 'frames 1-8' '$M/MANIFEST' &&
  grep -qx 'frames 1-8' '$R/MANIFEST'"
out=$(pipeline); rc=$?
check "the whole shot after 1-8 does frames 9-12" said 0 "$out" "mesh: running \(frames 9-12 to do"
check "and the render's MANIFEST claims it whole, with its contact sheet" bash -c \
  "[ -s '$R/contact_sheet.png' ] && grep -qx 'frames 1-12' '$R/MANIFEST'"

# ---- 4. nothing written before the input is known good -----------------------------------------------------------------
fresh
for m in broken open; do
  bad="$WORK/scenes/bad_$m.json"
  [ "$m" = open ] && head -n -1 "$WORK/meshes/cube.obj" > "$WORK/meshes/open.obj" # one triangle less: a hole
  sed "s#\"../meshes/cube.obj\"#\"../meshes/$m.obj\"#; s/\"name\": \"small_dam\"/\"name\": \"bad_$m\"/" "$scene" > "$bad"
  [ "$m" = broken ] && cp "$ROOT/assets/meshes/broken.obj" "$WORK/meshes/broken.obj"
  out=$("$ROOT/pipeline.sh" --no-build "$bad" 2>&1); rc=$?
  check "$m collider: pipeline.sh exits 2 naming the element and the file" said 2 "$out" "$m.obj: error: block.Mesh.file"
  check "$m collider: nothing is written (no precompute MANIFEST)" test ! -e "$DRENCH_OUT/bad_$m"
  expect_exit "$m collider: bake --print-key refuses the scene as loading it would" 2 "block\.Mesh\.file" \
    "$BIN/bake" --print-key "$bad"
done
expect_exit "an open collider mesh is refused, saying why" 2 "open.obj: error: block.Mesh.file: the mesh is not closed" \
  "$BIN/bake" "$WORK/scenes/bad_open.json"
"$BIN/bake" "$scene" -j 2 --frames 1-6 -q >/dev/null 2>&1
expect_exit "mesh of the whole shot after a bake of 6 frames exits 2 before writing" 2 \
  "MANIFEST: error: frame 7 has not been baked: the bake holds frames 1-6" "$BIN/mesh" "$scene" -q
check "and writes nothing" nothing_meshed

# ---- 5. messages name element, file and frame ------------------------------------------------------------------------
big="$WORK/scenes/big_dam.json"
sed 's/"voxel_size": 0.025/"voxel_size": 0.0015/; s/"name": "small_dam"/"name": "big_dam"/' "$scene" > "$big"
out=$(ulimit -v 2000000; "$BIN/bake" "$big" -j 2 -q 2>&1); rc=$?
check "out of memory: exit 1 naming the scene file, the element and the frame" said 1 "$out" \
  "big_dam.json: error: liquid 'water', frame 1: out of memory"
check "out of memory: nothing written" test ! -e "$DRENCH_OUT/big_dam"
