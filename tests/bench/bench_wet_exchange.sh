#!/usr/bin/env bash
# Capture and dripping on the reference liquid–hair code's own scenes, at their resolution, 2 threads:
#   capturing_test_2  assets/scenes/capturing_test_2.json (one 41-vertex strand under a jet, 64×64×10 cells of
#                     0.94 mm), frames 1–5 (the first 0.2 s); the reference took about 0.65 s of wall time per 1 ms step
#                     early on, on 2 cores of this kind of machine;
#   tree_structure    assets/scenes/tree_structure.json (21 tapered strands × 42 vertices in a box 80 % full on 64×64×14
#                     cells of 1.25 mm, a block and a ball intersecting), frames 1–5 (0.2 s); the reference's first
#                     step took about 3.5 s and it aborted at its second;
#   dragging_test     assets/scenes/dragging_test.json (one 42-vertex strand dragged through about 119k particles on
#                     64×64×14 cells of 1.25 mm) made whole as the reference runs it: the strand wet (Wetting, Film) with
#                     Drag, Capture and Dripping on, frames 1–5; the reference took about 2.0 s of wall time per 4 ms
#                     step;
#   dripping_test     assets/scenes/dripping_test.json (one horizontal 41-vertex strand of r = 37 µm, root clamped,
#                     loaded with film at H/r = 30, about 2.8 V_max per cell of 0.625 mm, middle dripping only,
#                     radius_scale 0.5, 96×96×15 cells), frames 1–5; the reference's run was not timed.
# Per scene: clock steps, seconds per step and per simulated second (the frame loop's wall time from progress.jsonl),
# seconds by phase (liquid transfers and pressure, hair, capture and dripping), the volume ledger's largest relative
# error, particles at the end. CSV (default out/bench/wet_exchange.csv), a gnuplot PNG of the seconds by phase, and a
# Markdown table on stdout.
# usage: bench_wet_exchange.sh [csv = out/bench/wet_exchange.csv] [frames = 5]
set -u
cd "$(dirname "$0")/../.."
csv=${1:-out/bench/wet_exchange.csv}
frames=${2:-5}
mkdir -p "$(dirname "$csv")"
make -s bin/bake bin/precompute >/dev/null || exit 1
work=$(mktemp -d "${TMPDIR:-/tmp}/drench-bench-wet.XXXXXX")
trap 'rm -rf "$work"' EXIT
export DRENCH_OUT="$work/out" DRENCH_CACHE="$work/cache"
echo "scene,steps,s_per_step,s_per_sim_s,p2g_g2p,pressure,hair,capture_drip,ledger_error,particles,reference_s_per_step" >"$csv"
echo "| scene | clock steps | s/step | s per simulated s | transfers | pressure | hair | capture+drip | ledger error | particles | reference s/step |"
echo "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"
for sc in capturing_test_2:0.65:0.001 tree_structure:3.5:0.004 dragging_test:2.0:0.004 dripping_test:nan:0.001; do
  IFS=: read -r name ref refdt <<<"$sc"
  python3 - "assets/scenes/$name.json" "$work/$name.json" "$frames" "$PWD/assets/meshes" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); s['shot']['frames'] = [1, int(sys.argv[3])]
for e in s['elements']:
    for c in e['components'].values():
        for k in ('file', 'curves', 'scalp'):
            if k in c: c[k] = sys.argv[4] + '/' + c[k].split('/')[-1]
if s['shot']['name'] == 'dragging_test': # the reference's scene is wet, with drag, capture and dripping
    for e in s['elements']:
        if e['type'] == 'hair':
            e['components'].update({'Wetting': {'liquid': 'water'}, 'Film': {'initial_ratio': 1, 'max_ratio': 6},
                                    'Drag': {}, 'Capture': {}, 'Dripping': {}})
json.dump(s, open(sys.argv[2], 'w'))
PY
  bin/precompute "$work/$name.json" >/dev/null 2>&1
  bin/bake "$work/$name.json" -j 2 -q >/dev/null 2>&1 || { echo "$name: bake failed"; continue; }
  python3 - "$DRENCH_OUT/$name/bake/progress.jsonl" "$name" "$ref" "$refdt" "$csv" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
name, ref, refdt, csv = sys.argv[2], float(sys.argv[3]), float(sys.argv[4]), sys.argv[5]
steps = sum(r['coupling_steps'] if r.get('coupling_steps') else r['liquid_substeps'] for r in rows)
sec = lambda k: sum(r['seconds'].get(k, 0.0) for r in rows)
total = sec('frame'); simt = rows[-1]['time']
tr, pr, ha, ex = sec('p2g') + sec('g2p'), sec('pressure'), sec('hair'), sec('capture_drip')
err = max(abs(r.get('volume_error', 0.0)) for r in rows)
line = [name, steps, total / steps, total / simt, tr, pr, ha, ex, err, rows[-1]['particles'], ref]
open(csv, 'a').write(','.join(str(x) for x in line) + '\n')
ref_text = 'not timed' if ref != ref else '%.2f (%.0f s per simulated s)' % (ref, ref / refdt)
print('| %s | %d | %.3f | %.1f | %.1f s | %.1f s | %.1f s | %.2f s | %.1e | %d | %s |' %
      (name, steps, total / steps, total / simt, tr, pr, ha, ex, err, rows[-1]['particles'], ref_text))
PY
done
if command -v gnuplot >/dev/null; then
  gnuplot -e "csv='$csv'; png='${csv%.csv}.png'" tests/bench/wet_exchange.gp 2>/dev/null && echo "plot: ${csv%.csv}.png"
fi
