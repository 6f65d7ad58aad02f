#!/usr/bin/env bash
# drench pipeline: precompute → bake → mesh → render for one scene, rerunning only what changed.
#
#   ./pipeline.sh [SCENE] [--force STAGE] [--from STAGE] [--frames A-B] [-j N] [--no-build]
#
# Each stage prints its cache key (`--print-key`); the key is compared with the MANIFEST in the stage's
# output folder, and a stage runs when the two differ, when it is forced, or when an earlier stage ran.
# SCENE defaults to assets/scenes/default.json. Outputs go to out/<shot>/ (DRENCH_OUT to change).
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
stages=(precompute bake mesh render)
scene=""; force=""; from=""; frames=""; threads=""; build=1

die() { echo "pipeline.sh: error: $*" >&2; exit 2; }
usage() { sed -n '2,9p' "$0" | sed 's/^# \{0,1\}//'; }
stage_index() { local i; for i in "${!stages[@]}"; do [ "${stages[$i]}" = "$1" ] && { echo "$i"; return; }; done
                die "unknown stage '$1' (stages: ${stages[*]})"; }

while [ $# -gt 0 ]; do
  case "$1" in
    -h|--help) usage; exit 0 ;;
    --force) [ $# -ge 2 ] || die "--force needs a stage"; force="$2"; stage_index "$2" >/dev/null; shift 2 ;;
    --from) [ $# -ge 2 ] || die "--from needs a stage"; from="$2"; stage_index "$2" >/dev/null; shift 2 ;;
    --frames) [ $# -ge 2 ] || die "--frames needs a range A-B"; frames="$2"; shift 2 ;;
    -j) [ $# -ge 2 ] || die "-j needs a thread count"; threads="$2"; shift 2 ;;
    --no-build) build=0; shift ;;
    -*) die "unknown option '$1' (see --help)" ;;
    *) [ -z "$scene" ] || die "more than one scene given"; scene="$1"; shift ;;
  esac
done
scene="${scene:-$here/assets/scenes/default.json}"
[ -f "$scene" ] || die "scene '$scene' not found"

t0=$EPOCHREALTIME
if [ "$build" = 1 ]; then
  # Builds only what is missing or out of date; installs missing Debian packages first.
  make -s -C "$here" deps
  make -s -C "$here" -j"$(nproc)" all >/dev/null
fi
bin="$here/bin"

extra=()
[ -n "$threads" ] && extra+=(-j "$threads")
first_stale=99
[ -n "$from" ] && first_stale=$(stage_index "$from")
ran=0; skipped=0
for i in "${!stages[@]}"; do
  st=${stages[$i]}
  if [ "$st" = render ] && ! "$bin/render" --available >/dev/null 2>&1; then
    echo "render: not available yet (skipped)"; continue
  fi
  key=$("$bin/$st" --print-key "$scene") || exit $?
  dir=$("$bin/$st" --print-out-dir "$scene") || exit $?
  have=""
  [ -f "$dir/MANIFEST" ] && have=$(awk '$1=="key"{print $2; exit}' "$dir/MANIFEST")
  reason=""
  if [ "$i" -ge "$first_stale" ]; then reason="an earlier stage ran or --from"
  elif [ "$st" = "$force" ]; then reason="--force"
  elif [ -z "$have" ]; then reason="no complete output yet"
  elif [ "$have" != "$key" ]; then reason="inputs changed"
  fi
  if [ -z "$reason" ]; then
    echo "$st: up to date (key $key)"; skipped=$((skipped + 1)); continue
  fi
  echo "$st: running ($reason)"
  args=("$scene" "${extra[@]}")
  [ -n "$frames" ] && [ "$st" != precompute ] && args+=(--frames "$frames")
  "$bin/$st" "${args[@]}"
  ran=$((ran + 1))
  [ "$i" -lt "$first_stale" ] && first_stale=$i
done
secs=$(awk -v a="$t0" -v b="$EPOCHREALTIME" 'BEGIN{printf "%.1f", b-a}')
echo "pipeline: $ran stage(s) ran, $skipped up to date, ${secs}s"
