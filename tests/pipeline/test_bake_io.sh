# Bake output written in the background: frames and checkpoints byte-identical to those written on the main
# thread (--sync-writes) for liquid, MPM and hair scenes; progress.jsonl and report.json tell the main thread's
# I/O seconds from the writer's; a SIGTERM still ends with every frame and the checkpoint on disk (exit 3) and the
# resumed bake is bit-identical; a write that fails in the background (disk full) ends the bake with exit 1 and a
# message naming the file, leaving neither the file nor its temporary file, and no checkpoint ahead of the frames.
source "$(dirname "$0")/lib.sh"
scene="$ROOT/assets/scenes/small_dam.json"
same_files() { # same_files DIR_A DIR_B COUNT: every frame and the checkpoint of A equal B's, COUNT frames
  local f ok=0
  for f in "$1"/frame.*.h5 "$1"/checkpoint.h5; do cmp -s "$f" "$2/$(basename "$f")" || { echo "differs: $f"; ok=1; }; done
  [ "$(ls "$1"/frame.*.h5 | wc -l)" -eq "$3" ] && [ "$(ls "$2"/frame.*.h5 | wc -l)" -eq "$3" ] && return $ok
}
no_tmp() { ! ls "$1" | grep -q '\.tmp\.'; }
ckpt_frame() { h5dump -a /frame "$1/checkpoint.h5" 2>/dev/null | awk '/\(0\):/ { print $2; exit }'; }

# 1. The same files either way.
a="$WORK/bg"; s="$WORK/sync"
"$BIN/bake" "$scene" -j 2 --out "$a" -q >/dev/null 2>&1
"$BIN/bake" "$scene" -j 2 --out "$s" --sync-writes -q >/dev/null 2>&1
ad="$a/small_dam/bake"; sd="$s/small_dam/bake"
check "frames and checkpoint written in the background equal those written on the main thread" same_files "$ad" "$sd" 12
"$BIN/bake" "$scene" -j 2 --frames 1-5 --out "$WORK/bg5" -q >/dev/null 2>&1
"$BIN/bake" "$scene" -j 2 --frames 1-5 --out "$WORK/sync5" --sync-writes -q >/dev/null 2>&1
check "a mid-shot checkpoint is the same either way" same_files "$WORK/bg5/small_dam/bake" "$WORK/sync5/small_dam/bake" 5
for data in mpm_drop hair_small; do
  "$BIN/bake" "$ROOT/tests/data/$data.json" -j 2 --frames 1-3 --out "$WORK/bg_$data" -q >/dev/null 2>&1
  "$BIN/bake" "$ROOT/tests/data/$data.json" -j 2 --frames 1-3 --out "$WORK/sync_$data" --sync-writes -q >/dev/null 2>&1
  check "$data: frames and checkpoint the same either way" same_files "$WORK/bg_$data/$data/bake" "$WORK/sync_$data/$data/bake" 3
done
check "both bakes write their MANIFEST" test -f "$ad/MANIFEST" -a -f "$sd/MANIFEST"
check "no temporary file is left" no_tmp "$ad"

# 2. What the I/O figures say.
check "every progress line tells the main thread's I/O seconds from the writer's" bash -c "
  [ \$(grep -c '\"io\":[0-9.]*,\"frame\":[0-9.]*},\"io\":{\"background\":true,\"wait\":[0-9.]*,\"writer\":[0-9.]*}}\$' '$ad/progress.jsonl') -eq 12 ] &&
  [ \$(grep -c '\"io\":{\"background\":false,\"wait\":0.000000,\"writer\":0.000000}}\$' '$sd/progress.jsonl') -eq 12 ]"
check "report.json sums them: 24 files, main thread, wait and writer seconds, share of the wall time" python3 -c "
import json, sys
b = json.load(open('$ad/report.json')); s = json.load(open('$sd/report.json'))
io, so = b['io'], s['io']
ok = (io['background'] is True and so['background'] is False and io['files'] == 24 and so['files'] == 24 and
      io['writer_seconds'] > 0 and so['writer_seconds'] == 0 and 0 <= io['wait_seconds'] <= io['main_thread_seconds'] and
      abs(io['main_thread_seconds'] - b['seconds_by_phase']['io']) < 1e-6 and
      abs(io['main_thread_share'] - io['main_thread_seconds'] / b['seconds_total']) < 1e-3)
sys.exit(0 if ok else 1)"
check "bake --help lists --sync-writes" bash -c "'$BIN/bake' --help | grep -q -- '--sync-writes'"

# 3. SIGTERM while frames are being written: exit 3 after the pending files are on disk, then resume.
stage_scene small_dam.json >/dev/null
slow="$WORK/scenes/slow_dam.json" # 8 times the particles, so that the signal comes well before the end
sed 's/"voxel_size": 0.025/"voxel_size": 0.0125/; s/"name": "small_dam"/"name": "slow_dam"/; s/"frames": \[1, 12\]/"frames": [1, 8]/' \
  "$WORK/scenes/small_dam.json" > "$slow"
u="$WORK/uninterrupted"; t="$WORK/term"
"$BIN/bake" "$slow" -j 2 --out "$u" -q >/dev/null 2>&1
"$BIN/bake" "$slow" -j 2 --out "$t" -q >"$WORK/term.log" 2>&1 &
pid=$!
td="$t/slow_dam/bake"
for _ in $(seq 1 600); do [ -f "$td/frame.0003.h5" ] && break; sleep 0.05; done
kill -TERM $pid 2>/dev/null
wait $pid; rc=$?
last=$(ls "$td"/frame.*.h5 2>/dev/null | sed 's/.*frame\.0*\([0-9]*\)\.h5/\1/' | sort -n | tail -1)
check "SIGTERM ends the bake with exit 3 before the shot's end" bash -c "[ $rc -eq 3 ] && [ '${last:-0}' -ge 3 ] && [ '${last:-0}' -lt 8 ]"
ck=$(ckpt_frame "$td")
check "the checkpoint holds the last frame on disk, and every frame before it is there" bash -c "
  [ '$ck' = '$last' ] && [ \$(ls '$td'/frame.*.h5 | wc -l) -eq '$last' ]"
check "report.json of the stopped bake says interrupted" grep -q '"status": "interrupted"' "$td/report.json"
check "the stopped bake leaves no temporary file and no MANIFEST" bash -c "! ls '$td' | grep -q '\.tmp\.' && [ ! -f '$td/MANIFEST' ]"
"$BIN/bake" "$slow" -j 2 --out "$t" --resume -q >/dev/null 2>&1; rc=$?
check "the resumed bake is bit-identical to an uninterrupted one" bash -c "[ $rc -eq 0 ] && [ -f '$td/MANIFEST' ]"
same_frames_only() { local f ok=0; for f in "$1"/frame.*.h5; do cmp -s "$f" "$2/$(basename "$f")" || ok=1; done
                     [ "$(ls "$1"/frame.*.h5 | wc -l)" -eq 8 ] && return $ok; }
check "resumed frames equal the uninterrupted bake's" same_frames_only "$u/slow_dam/bake" "$td"

# 4. Disk full in the background. The temporary file of frame 4 is made a link to /dev/full before bake starts
# (the shell's pid is bake's after exec, and the temporary name carries the pid): its writes fail with ENOSPC
# on the writer thread, as on a full disk, for root too. A fresh bake removes frame.* files first, so this one
# resumes after frame 2.
if [ -e /dev/full ]; then
  f="$WORK/full"; fd="$f/small_dam/bake"
  "$BIN/bake" "$scene" -j 2 --frames 1-2 --out "$f" -q >/dev/null 2>&1
  bash -c 'ln -s /dev/full "$1/frame.0004.h5.tmp.$$" && exec "$2" "$3" -j 2 --out "$4" --resume -q' _ \
    "$fd" "$BIN/bake" "$scene" "$f" >"$WORK/full.log" 2>&1; rc=$?
  check "a background write failure exits 1 naming the file" \
    bash -c "[ $rc -eq 1 ] && grep -q '^bake: .*frame.0004.h5: error: .*No space left on device' '$WORK/full.log'"
  check "the failed frame and its temporary file are gone" bash -c "[ ! -e '$fd/frame.0004.h5' ] && ! ls -a '$fd' | grep -q '\.tmp\.'"
  ck=$(ckpt_frame "$fd")
  check "the frames before it are on disk and the checkpoint is not ahead of them" \
    bash -c "[ -f '$fd/frame.0003.h5' ] && [ '$ck' = 3 ]"
  check "report.json of the failed bake says failed and names the file" \
    bash -c "grep -q '\"status\": \"failed\"' '$fd/report.json' && grep -q 'frame.0004.h5' '$fd/report.json' && [ ! -f '$fd/MANIFEST' ]"
  "$BIN/bake" "$scene" -j 2 --out "$f" --resume -q >/dev/null 2>&1; rc=$?
  check "resumed after the failure, the bake is bit-identical" bash -c "[ $rc -eq 0 ] && [ -f '$fd/MANIFEST' ]"
  same_frames_12() { local x ok=0; for x in "$ad"/frame.*.h5; do cmp -s "$x" "$fd/$(basename "$x")" || ok=1; done; return $ok; }
  check "resumed frames equal the uninterrupted bake's (disk full)" same_frames_12
else
  echo "SKIP test_bake_io: no /dev/full, the disk-full checks did not run"
fi
