#!/usr/bin/env bash
# Runs every test binary given as argument (cmocka) and every tests/pipeline/test_*.sh script,
# and ends with one line `N passed, N failed`. A binary that crashes counts as one failure.
set -u
cd "$(dirname "$0")/.."
passed=0; failed=0; failures=(); skips=()
log_dir=out/test-logs; mkdir -p "$log_dir"
t0=$(date +%s)
for bin in "$@"; do
  name=$(basename "$bin"); log="$log_dir/$name.log"
  start=$EPOCHREALTIME
  CMOCKA_MESSAGE_OUTPUT=stdout "$bin" >"$log" 2>&1; rc=$?
  secs=$(awk -v a="$start" -v b="$EPOCHREALTIME" 'BEGIN{printf "%.1f", b-a}')
  p=$(grep -Eo '^\[  PASSED  \] [0-9]+' "$log" | awk '{s+=$4} END{print s+0}')
  f=$(grep -Eo '^\[  FAILED  \] [0-9]+ test' "$log" | awk '{s+=$4} END{print s+0}')
  if [ "$rc" -ne 0 ] && [ "$f" -eq 0 ]; then f=1; fi
  passed=$((passed + p)); failed=$((failed + f))
  if [ "$f" -ne 0 ]; then failures+=("$name"); echo "FAIL $name ($p passed, $f failed, ${secs}s) — see $log"; grep -E '^\[  (FAILED|ERROR)|error|Failure' "$log" | head -20
  else echo "ok   $name ($p tests, ${secs}s)"; fi
done
for script in tests/pipeline/test_*.sh; do
  [ -f "$script" ] || continue
  name=$(basename "$script" .sh); log="$log_dir/$name.log"
  start=$EPOCHREALTIME
  bash "$script" >"$log" 2>&1; rc=$?
  secs=$(awk -v a="$start" -v b="$EPOCHREALTIME" 'BEGIN{printf "%.1f", b-a}')
  p=$(grep -c '^PASS ' "$log"); f=$(grep -c '^FAIL ' "$log")
  while IFS= read -r line; do skips+=("$line"); done < <(grep '^SKIP ' "$log")
  if [ "$rc" -ne 0 ] && [ "$f" -eq 0 ]; then f=1; fi
  passed=$((passed + p)); failed=$((failed + f))
  if [ "$f" -ne 0 ]; then failures+=("$name"); echo "FAIL $name ($p passed, $f failed, ${secs}s) — see $log"; grep '^FAIL ' "$log" | head -20
  else echo "ok   $name ($p checks, ${secs}s)"; fi
done
for line in "${skips[@]+"${skips[@]}"}"; do echo "$line"; done
echo "tests took $(( $(date +%s) - t0 ))s"
echo "$passed passed, $failed failed"
[ "$failed" -eq 0 ]
