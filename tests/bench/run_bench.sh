#!/usr/bin/env bash
# Runs every benchmark given as argument (a binary, or a bash script bench_NAME.sh): bench_NAME writes
# out/bench/NAME*.csv (first argument) and a markdown table on stdout; tests/bench/NAME.gp (gnuplot) turns
# its CSVs into PNG plots. Timings are measured here and never asserted. Ends with out/bench/summary.md.
set -u
cd "$(dirname "$0")/../.."
mkdir -p out/bench
summary=out/bench/summary.md
{
  echo "# drench benchmarks"
  echo
  echo "- date: $(date -u +%Y-%m-%dT%H:%M:%SZ)"
  echo "- machine: $(nproc) cores, $(awk -F: '/model name/{print $2; exit}' /proc/cpuinfo | sed 's/^ *//')"
  echo "- build: $(git rev-parse --short HEAD 2>/dev/null || echo unknown)"
  echo
} > "$summary"
status=0
for bin in "$@"; do
  name=$(basename "$bin" .sh); name=${name#bench_}
  run=("$bin"); [ "${bin%.sh}" != "$bin" ] && run=(bash "$bin")
  echo "== $name"
  if ! "${run[@]}" "out/bench/$name.csv" | tee "out/bench/$name.md"; then echo "bench $name failed" >&2; status=1; fi
  { echo "## $name"; echo; cat "out/bench/$name.md"; echo; } >> "$summary"
  if [ -f "tests/bench/$name.gp" ] && command -v gnuplot >/dev/null; then
    (cd out/bench && gnuplot "../../tests/bench/$name.gp") || { echo "plot $name failed" >&2; status=1; }
  fi
done
ls out/bench/*.png 2>/dev/null | sed 's/^/plot: /'
echo "summary: $summary"
exit $status
