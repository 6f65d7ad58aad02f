#!/usr/bin/env bash
# A 64 × 64-vertex panel (7,938 triangles) dipped into a tank and pulled out, 2 threads: the shipped cloth_dip shot
# (assets/scenes/cloth_dip.json: a towel pinned along its top edge lowered into 47,520 particles by its Motion, held
# and lifted) with the towel remeshed to 64 × 64 vertices (same 0.3 m square, alternating diagonals), over frames
# 1–FRAMES (default 60: down by frame 24, held to 36, out by 54). Per frame from progress.jsonl: seconds, the cloth's
# seconds (its predict and commit; its solves inside the loop are the loop's), the coupled loop's seconds and its
# share of the frame, CG iterations of the cloth's solves, coupling iterations; a Markdown table of their means and
# maxima over the frames, a CSV per frame (default out/bench/cloth_tank.csv).
# usage: bench_cloth_tank.sh [csv = out/bench/cloth_tank.csv] [frames = 60]
set -u
cd "$(dirname "$0")/../.."
csv=${1:-out/bench/cloth_tank.csv}
frames=${2:-60}
mkdir -p "$(dirname "$csv")"
make -s bin/bake >/dev/null || exit 1
work=$(mktemp -d "${TMPDIR:-/tmp}/drench-bench-cloth-tank.XXXXXX")
trap 'rm -rf "$work"' EXIT
python3 - "$PWD" "$work" "$frames" <<'PY'
import json, sys
root, work, frames = sys.argv[1], sys.argv[2], int(sys.argv[3])
n = 64
lines = []
for j in range(n):
    for i in range(n):
        lines.append("v %.7f 0 %.7f" % (i / (n - 1) - 0.5, j / (n - 1) - 0.5))
idx = lambda i, j: i + n * j + 1
for j in range(n - 1):
    for i in range(n - 1):
        a, b, c, d = idx(i, j), idx(i + 1, j), idx(i, j + 1), idx(i + 1, j + 1)
        tris = [(a, c, b), (b, c, d)] if (i + j) % 2 else [(a, c, d), (a, d, b)]
        lines += ["f %d %d %d" % t for t in tris]
open(work + "/panel64.obj", "w").write("\n".join(lines) + "\n")
s = json.load(open(root + "/assets/scenes/cloth_dip.json"))
s["shot"]["name"] = "cloth_tank"; s["shot"]["frames"] = [1, frames]
s["elements"][1]["components"]["Mesh"]["file"] = work + "/panel64.obj"
json.dump(s, open(work + "/tank.json", "w"))
PY
t0=$(date +%s.%N)
bin/bake "$work/tank.json" -j 2 --out "$work/out" >"$work/bake.log" 2>&1 || { tail -5 "$work/bake.log" >&2; exit 1; }
t1=$(date +%s.%N)
warnings=$(grep -ci warn "$work/bake.log")
python3 - "$work/out/cloth_tank/bake/progress.jsonl" "$csv" "$(awk -v a="$t0" -v b="$t1" 'BEGIN{print b - a}')" "$warnings" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1]) if l.strip()]
rows = [r for r in rows if "frame" in r and "cloth_vertices" in r]
with open(sys.argv[2], "w") as f:
    f.write("frame,seconds,cloth_seconds,coupling_seconds,coupling_share,cloth_cg_iterations,coupling_iterations,coupling_steps,liquid_substeps\n")
    for r in rows:
        sec = r["seconds"]["frame"]; cs = r.get("coupling_seconds", 0.0)
        f.write("%d,%.4f,%.4f,%.4f,%.3f,%d,%d,%d,%d\n" % (r["frame"], sec, r["seconds"].get("cloth", 0.0), cs, cs / sec,
                r["cloth_cg_iterations"], r.get("coupling_iterations", 0), r.get("coupling_steps", 0), r["liquid_substeps"]))
def stat(key):
    v = [key(r) for r in rows]
    return sum(v) / len(v), max(v)
s_mean, s_max = stat(lambda r: r["seconds"]["frame"])
c_mean, _ = stat(lambda r: r.get("coupling_seconds", 0.0))
k_mean, k_max = stat(lambda r: r["seconds"].get("cloth", 0.0))
cg_mean, cg_max = stat(lambda r: r["cloth_cg_iterations"])
it_mean, it_max = stat(lambda r: r.get("coupling_iterations", 0) / max(1, r.get("coupling_steps", 1)))
print("| panel | frames | s / frame (mean, max) | coupled loop's share | cloth predict + commit s / frame | CG iterations / frame (mean, max) | coupling iterations / step (mean, max) | bake wall s | warnings |")
print("|---|---|---|---|---|---|---|---|---|")
print("| 64 × 64 (4,096 vertices) | %d | %.2f, %.2f | %.0f %% | %.2f | %.1f, %d | %.2f, %.2f | %.0f | %s |" % (
    len(rows), s_mean, s_max, 100 * c_mean / s_mean, k_mean, cg_mean, cg_max, it_mean, it_max, float(sys.argv[3]), sys.argv[4]))
PY
