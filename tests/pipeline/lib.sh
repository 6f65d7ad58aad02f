# Shared helpers of the pipeline tests: each check prints "PASS name" or "FAIL name: why"; the runner counts them.
set -u
ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
BIN="$ROOT/bin"
WORK=$(mktemp -d "${TMPDIR:-/tmp}/drench-test.XXXXXX")
trap 'rm -rf "$WORK"' EXIT
export DRENCH_OUT="$WORK/out" DRENCH_CACHE="$WORK/cache" CI=1

pass() { echo "PASS $1"; }
fail() { echo "FAIL $1: $2"; }
# check NAME COMMAND...: passes when the command succeeds
check() { local n="$1"; shift; if "$@"; then pass "$n"; else fail "$n" "command failed: $*"; fi; }
# expect_exit NAME CODE PATTERN COMMAND...: exit code and a stderr pattern (grep -E)
expect_exit() {
  local n="$1" code="$2" pat="$3"; shift 3
  local out rc
  out=$("$@" 2>&1); rc=$?
  if [ "$rc" -ne "$code" ]; then fail "$n" "exit $rc, expected $code; output: $(echo "$out" | head -3)"; return; fi
  if ! echo "$out" | grep -Eq -- "$pat"; then fail "$n" "message lacks /$pat/: $(echo "$out" | head -3)"; return; fi
  pass "$n"
}
# Copies a scene and the meshes it needs into $WORK so tests may edit them.
stage_scene() {
  mkdir -p "$WORK/scenes" "$WORK/meshes"
  cp "$ROOT"/assets/meshes/*.obj "$WORK/meshes/"
  cp "$ROOT/assets/scenes/$1" "$WORK/scenes/$1"
  echo "$WORK/scenes/$1"
}
