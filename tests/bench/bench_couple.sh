#!/usr/bin/env bash
# Coupled hair–liquid benchmark: assets/scenes/fur_tank.json (300 strands × 9 vertices on a ball swept through a tank of
# 46,000 particles on a 30×20×16 grid) baked for `frames` frames (default 3) at solver.coupling_iterations 1 to 5
# (coupling_tolerance 1e-12, so every step takes them all), 2 threads: seconds per clock step (the bake's wall time over
# its coupled steps), the iterations taken and the largest final relative change of a step (frame caches'
# /diagnostics), and the hair's velocities at the last frame against the 5-iteration run's (the change the
# iterations still make). CSV (default out/bench/couple.csv) and a Markdown table on stdout.
# usage: bench_couple.sh [csv = out/bench/couple.csv] [frames = 3]
set -u
cd "$(dirname "$0")/../.."
csv=${1:-out/bench/couple.csv}
frames=${2:-3}
mkdir -p "$(dirname "$csv")"
make -s bin/bake >/dev/null || exit 1
work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
echo "iterations,steps,seconds_per_step,iterations_taken,change_max,hair_velocity_diff" > "$csv"
for k in 5 1 2 3 4; do
    sed -e "s/\"coupling_iterations\": 3, \"coupling_tolerance\": 1e-2/\"coupling_iterations\": $k, \"coupling_tolerance\": 1e-12/" \
        -e "s#\"../meshes/#\"$PWD/assets/meshes/#g" assets/scenes/fur_tank.json > "$work/s$k.json"
    t0=$(date +%s.%N)
    bin/bake "$work/s$k.json" --frames 1-"$frames" --out "$work/o$k" -q -j 2 >/dev/null 2>&1 || { echo "bench_couple: bake failed" >&2; exit 1; }
    t1=$(date +%s.%N)
    f=$(printf "%s/o%s/fur_tank/bake/frame.%04d.h5" "$work" "$k" "$frames")
    steps=0; its=0; ch=0
    for i in $(seq 1 "$frames"); do
        g=$(printf "%s/o%s/fur_tank/bake/frame.%04d.h5" "$work" "$k" "$i")
        s=$(h5dump -d /diagnostics/coupling_steps "$g" | awk '/\(0\):/{print $2; exit}')
        n=$(h5dump -d /diagnostics/coupling_iterations "$g" | awk '/\(0\):/{print $2; exit}')
        c=$(h5dump -d /diagnostics/coupling_change_max "$g" | awk '/\(0\):/{print $2; exit}')
        steps=$((steps + s)); its=$((its + n))
        ch=$(awk -v a="$ch" -v b="$c" 'BEGIN{print (b > a) ? b : a}')
    done
    h5dump -d /fur/velocity -y -w 0 "$f" | grep -E '^ *[-0-9]' | tr -d ' ' | tr ',' '\n' | grep -v '^$' > "$work/v$k"
    diff=$(paste "$work/v$k" "$work/v5" | awk '{d = $1 - $2; if (d < 0) d = -d; if (d > m) m = d} END{print m + 0}')
    sps=$(awk -v a="$t0" -v b="$t1" -v s="$steps" 'BEGIN{print (b - a) / s}')
    echo "$k,$steps,$sps,$its,$ch,$diff" >> "$csv"
done
echo "| coupling iterations | coupled steps | s per step (wall, 2 threads) | iterations taken | largest final change | max abs hair velocity diff vs 5 iterations (m/s) |"
echo "|---|---|---|---|---|---|"
tail -n +2 "$csv" | sort -n | awk -F, '{printf "| %s | %s | %.3f | %s | %.2e | %.2e |\n", $1, $2, $3, $4, $5, $6}'
