#!/usr/bin/env bash
# Wet hair benchmark, three parts, each baked by bin/precompute and bin/bake as a user runs them (cohesion tables in a
# cache of its own, so their build is part of the figures), timings from each bake's progress.jsonl. Markdown tables
# on stdout; CSVs next to the first (default out/bench/wet.csv); tests/bench/wet.gp draws wet_groom.png and
# wet_shake.png.
#  1. cylinder_2 (wet.csv): assets/scenes/cylinder_2.json, two hanging strands of 42 vertices bridged along their
#     length, 96 frames at 40 hair steps a frame (1/960 s), on 1 and 2 threads: seconds per hair step (the bake's
#     seconds.hair over its hair steps; the wall time over them beside it, start-up and frame writes included) against
#     the reference code's 0.29 s per step on a 2-core machine of this kind. The reference builds a 48³ grid for this
#     scene and steps on its own time step; drench builds no grid for a scene without liquid.
#  2. 1,024 strands × 30 vertices with cohesion (wet_groom.csv per run, wet_groom_frames.csv per frame): the groom of
#     tests/bench/bench_hair part 1 (3 cm strands rooted on a 3 cm square patch at 0.97 mm spacing, tilted at random by
#     up to 14° so that neighbours cross; r = 50 µm, contact stiffness 10 N/m, friction 0.2), wet (Film.initial_ratio
#     3: films 0.15 mm in radius, so strands passing within 0.3 mm of each other bridge), cohesion on, gravity, roots
#     at rest; `frames` frames (default 3) at 10 hair steps a frame (1/240 s), HairSolver.preconditioner block and
#     cluster at tolerance 1e-8 (iteration cap 5,000), on 1 and 2 threads: CG iterations, seconds and bridges per step;
#     the answer's agreement at every frame: the largest distance of a vertex between block and cluster, and of each
#     from block at tolerance 1e-11 (`tight`, the converged answer: what the tolerance allows is block's own distance
#     from it); whether 2 threads reproduce 1 thread bit for bit (the frame caches, byte for byte); the clumps the
#     bridges make (strands joined by bridges, from the checkpoint), which the cluster preconditioner factors whole. A
#     control run (`cohesion_off`: block, 1 thread, 1 frame, Cohesion.scale 0) finds the same kind of bridges but
#     leaves their rows out of the solve: against it, the first frame's CG iterations tell the bridges' rows are in
#     the CG's matrix (bridge.c adds them to K_G with dr_lag_add_global).
#  3. wet fur shot (wet_shake.csv, per frame): assets/scenes/hair_shake.json (600 curly strands × 15 vertices on a
#     shaken ball) with "Wetting": {} and "Film": {"initial_ratio": 3} added to its hair, 48 frames on 2 threads:
#     seconds per frame by phase (hair solve: the hair step less the wet phases; bridges: finding them, their rows
#     and the film's load on the solve; film along the strands; cross-hair flow), with the dry hair_shake's seconds per
#     frame beside it.
# `other CPUs` is the mean number of CPUs other processes kept busy during a run (from /proc/stat, less the bake's
# own CPU time): timings on a shared machine are only comparable when it is near 0. Nothing is repeated.
# usage: bench_wet.sh [csv = out/bench/wet.csv] [part = all | cylinder | groom | shake] [frames = 3 (part 2)]
set -u
cd "$(dirname "$0")/../.."
root=$PWD
csv=${1:-out/bench/wet.csv}
part=${2:-all}
gframes=${3:-3}
case $part in all|cylinder|groom|shake) ;; *) echo "bench_wet: part must be all, cylinder, groom or shake" >&2; exit 2 ;; esac
mkdir -p "$(dirname "$csv")"
base=${csv%.csv}
work=$(mktemp -d "${TMPDIR:-/tmp}/drench-bench-wet.XXXXXX")
trap 'rm -rf "$work"' EXIT
cache=$work/cache

# timed LOG CMD...: runs CMD (output to LOG) and prints "wall_seconds other_cpus"; fails when CMD fails.
timed() {
  python3 - "$@" <<'PY'
import os, subprocess, sys, time
def busy():
    with open("/proc/stat") as f:
        v = [int(x) for x in f.readline().split()[1:9]]
    return (v[0] + v[1] + v[2] + v[5] + v[6] + v[7]) / os.sysconf("SC_CLK_TCK")  # idle and iowait left out
log, cmd = sys.argv[1], sys.argv[2:]
m0, t0 = busy(), time.monotonic()
with open(log, "w") as lf:
    p = subprocess.Popen(cmd, stdout=lf, stderr=subprocess.STDOUT)
    _, status, ru = os.wait4(p.pid, 0)
t1, m1 = time.monotonic(), busy()
other = max(0.0, (m1 - m0 - (ru.ru_utime + ru.ru_stime)) / (t1 - t0))
print("%.3f %.2f" % (t1 - t0, other))
sys.exit(0 if os.waitstatus_to_exitcode(status) == 0 else 1)
PY
}
die_log() { echo "bench_wet: $1 failed:" >&2; tail -5 "$2" >&2; exit 1; }
load() { awk '{ print $1 }' /proc/loadavg; }

echo "machine: $(nproc) cores; load average $(load) at the start"
echo

# ---- 1. cylinder_2 --------------------------------------------------------------------------------------------------
if [ "$part" = all ] || [ "$part" = cylinder ]; then
  scene=assets/scenes/cylinder_2.json
  res=$(timed "$work/cyl_pre.log" bin/precompute "$scene" --cache "$cache" --out "$work/out" -j 2) ||
    die_log "precompute of cylinder_2" "$work/cyl_pre.log"
  read -r pre _ <<<"$res"
  echo "scene,threads,frames,hair_steps,wall_s,hair_s,solve_s,film_s,cross_flow_s,bridges_s,s_per_step,wall_s_per_step,reference_s_per_step,ratio_to_reference,cg_per_step,bridges_last,other_cpus" > "$csv"
  for j in 1 2; do
    out=$work/cyl$j
    res=$(timed "$out.log" bin/bake "$scene" --cache "$cache" --out "$out" -j $j -q) ||
      die_log "bake of cylinder_2 on $j thread(s)" "$out.log"
    read -r wall other <<<"$res"
    python3 - "$out/cylinder_2/bake/progress.jsonl" "$j" "$wall" "$other" >> "$csv" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
j, wall, other = int(sys.argv[2]), float(sys.argv[3]), float(sys.argv[4])
steps = sum(r["hair_substeps"] for r in rows)
sec = lambda k: sum(r["seconds"].get(k, 0.0) for r in rows)
hair, film, cross, bridges = sec("hair"), sec("film"), sec("cross_flow"), sec("bridges")
ref = 0.29
print("cylinder_2,%d,%d,%d,%.3f,%.4f,%.4f,%.4f,%.4f,%.4f,%.3e,%.3e,%.2f,%.4f,%.1f,%d,%.2f" % (
    j, len(rows), steps, wall, hair, hair - film - cross - bridges, film, cross, bridges, hair / steps, wall / steps,
    ref, hair / steps / ref, sum(r["hair_cg_iterations"] for r in rows) / steps, rows[-1]["hair_bridges"], other))
PY
  done
  python3 - "$csv" "$pre" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
print("### 1. cylinder_2: seconds per hair step against the reference code's 0.29 s/step")
print()
print("precompute (two cohesion tables, 256²): %.2f s wall" % float(sys.argv[2]))
print()
print("| threads | frames | hair steps | s/step (hair) | of which solve, film, cross flow, bridges | wall s/step | s per simulated s | ratio to 0.29 s | drench faster by | CG it./step | bridges | other CPUs |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|")
for r in rows:
    n = float(r["hair_steps"])
    print("| %s | %s | %s | %s | %.2e, %.2e, %.2e, %.2e | %s | %.2f | %s | %.0f× | %s | %s | %s |" % (
        r["threads"], r["frames"], r["hair_steps"], r["s_per_step"], float(r["solve_s"]) / n, float(r["film_s"]) / n,
        float(r["cross_flow_s"]) / n, float(r["bridges_s"]) / n, r["wall_s_per_step"],
        float(r["hair_s"]) / (float(r["frames"]) / 24), r["ratio_to_reference"],
        1 / float(r["ratio_to_reference"]), r["cg_per_step"], r["bridges_last"], r["other_cpus"]))
print()
print("What differs: the reference code builds a 48³ grid for this scene and steps on its own time step; drench builds")
print("no grid for hair without liquid and takes 40 hair steps a frame (1/960 s), so the steps compared are not of the")
print("same length. s/step (hair) is the bake's hair phase over its steps; wall s/step includes start-up and frame writes.")
print()
PY
fi

# ---- 2. 1,024 strands × 30 vertices with cohesion ------------------------------------------------------------------
if [ "$part" = all ] || [ "$part" = groom ]; then
  g=$work/groom
  mkdir -p "$g"
  # the groom (bench_hair part 1's construction) and one scene per run: NAME PRECOND FRAMES [Cohesion.scale]
  python3 - "$g" <<'PY'
import math, random, sys
n, nv, L, patch, tilt = 32, 30, 0.03, 0.03, math.radians(14)
rnd = random.Random(7)
with open(sys.argv[1] + "/patch.obj", "w") as f:
    f.write("# 32 x 32 strands x 30 vertices, 3 cm, rooted 0.97 mm apart, tilted by up to 14 degrees (bench_wet)\n")
    k = 1
    for i in range(n):
        for j in range(n):
            a, ph = tilt * rnd.random(), 2 * math.pi * rnd.random()
            d = (math.sin(a) * math.cos(ph), -math.cos(a), math.sin(a) * math.sin(ph))
            r = (patch * i / (n - 1), 0.0, patch * j / (n - 1))
            for v in range(nv):
                f.write("v %.17g %.17g %.17g\n" % tuple(r[c] + d[c] * L * v / (nv - 1) for c in range(3)))
            f.write("l " + " ".join(str(k + v) for v in range(nv)) + "\n")
            k += nv
PY
  # scene_for NAME PRECOND FRAMES COHESION_SCALE TOLERANCE: writes $g/NAME.json, prints its path
  scene_for() {
    python3 - "$g" "$@" <<'PY'
import json, sys
g, name, pc, frames, scale, tol = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4]), float(sys.argv[5]), float(sys.argv[6])
comp = {"Groom": {"curves": "patch.obj"},
        "CollisionResponse": {"stiffness": 10, "friction": 0.2},
        "HairSolver": {"preconditioner": pc, "tolerance": tol, "max_iterations": 5000, "substeps": 10},
        "Wetting": {}, "Film": {"initial_ratio": 3}, "Cohesion": {"scale": scale}}
s = {"shot": {"name": name, "fps": 24, "frames": [1, frames], "gravity": [0, -9.81, 0]},
     "elements": [{"name": "patch", "type": "hair", "components": comp}]}
json.dump(s, open("%s/%s.json" % (g, name), "w"), indent=1)
print("%s/%s.json" % (g, name))
PY
  }
  res=$(timed "$g/pre.log" bin/precompute "$(scene_for wet_block block "$gframes" 1 1e-8)" --cache "$cache" --out "$g/out" -j 2) ||
    die_log "precompute of the wet groom" "$g/pre.log"
  read -r gpre _ <<<"$res"
  frames_csv=${base}_groom_frames.csv
  echo "run,precond,threads,frame,steps,cg_iterations,not_converged,residual,contacts,bridges,hair_s,solve_s,film_s,cross_flow_s,bridges_s" > "$frames_csv"
  # RUN PRECOND THREADS FRAMES COHESION_SCALE TOLERANCE; one scene per RUN_PRECOND, each thread count baked into its
  # own folder, so that the frame caches of 1 and 2 threads can be compared byte for byte
  runs=("wet block 1 $gframes 1 1e-8" "wet block 2 $gframes 1 1e-8" "wet cluster 1 $gframes 1 1e-8"
        "wet cluster 2 $gframes 1 1e-8" "tight block 1 $gframes 1 1e-11" "cohesion_off block 1 1 0 1e-8")
  for r in "${runs[@]}"; do
    read -r run pc j fr scale tol <<<"$r"
    name=${run}_$pc
    sc=$(scene_for "$name" "$pc" "$fr" "$scale" "$tol")
    res=$(timed "$g/${name}_$j.log" bin/bake "$sc" --cache "$cache" --out "$g/out$j" -j "$j" -q) ||
      die_log "bake of the wet groom ($name, $j thread(s))" "$g/${name}_$j.log"
    read -r wall other <<<"$res"
    echo "$run $pc $j $wall $other $(load)" >> "$g/runs.txt"
    python3 - "$g/out$j/$name/bake/progress.jsonl" "$run" "$pc" "$j" >> "$frames_csv" <<'PY'
import json, sys
for l in open(sys.argv[1]):
    r = json.loads(l)
    s = r["seconds"]
    wet = s["film"] + s["cross_flow"] + s["bridges"]
    print("%s,%s,%s,%d,%d,%d,%d,%.3g,%d,%d,%.4f,%.4f,%.4f,%.4f,%.4f" % (
        sys.argv[2], sys.argv[3], sys.argv[4], r["frame"], r["hair_substeps"], r["hair_cg_iterations"],
        r["hair_not_converged"], r["hair_residual"], r["hair_contacts"], r["hair_bridges"], s["hair"], s["hair"] - wet,
        s["film"], s["cross_flow"], s["bridges"]))
PY
  done
  # agreement, determinism and clumps from the frame caches and checkpoints (h5dump, all digits)
  python3 - "$g" "$gframes" "$frames_csv" "${base}_groom.csv" "$gpre" <<'PY'
import csv, subprocess, sys
g, frames, fcsv, rcsv, pre = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4], float(sys.argv[5])
def h5(path, dset):
    out = subprocess.run(["h5dump", "-y", "-w", "0", "-m", "%.17g", "-d", dset, path], capture_output=True, text=True,
                         check=True).stdout
    body = out[out.index("DATA {") + 6:]
    return [float(x) for x in body[:body.index("}")].replace(",", " ").split()]
def bake(run, pc, j): return "%s/out%s/%s_%s/bake" % (g, j, run, pc)
def frame(run, pc, j, f): return "%s/frame.%04d.h5" % (bake(run, pc, j), f)
def positions(run, pc, f): return h5(frame(run, pc, 1, f), "/patch/position")
rest = []
for line in open(g + "/patch.obj"):
    if line.startswith("v "): rest += [float(x) for x in line.split()[1:4]]
def maxdist(a, b):
    assert len(a) == len(b)
    return max(((a[i] - b[i]) ** 2 + (a[i + 1] - b[i + 1]) ** 2 + (a[i + 2] - b[i + 2]) ** 2) ** 0.5
               for i in range(0, len(a), 3))
agree = []  # per frame: block from cluster, block from tight, cluster from tight, the largest move from the groom
for f in range(1, frames + 1):
    xb, xc, xt = positions("wet", "block", f), positions("wet", "cluster", f), positions("tight", "block", f)
    agree.append((maxdist(xb, xc), maxdist(xb, xt), maxdist(xc, xt), maxdist(xt, rest)))
d_bc, d_bt, d_ct, moved = agree[-1]
def identical(pc):
    return all(subprocess.run(["cmp", "-s", frame("wet", pc, 1, f), frame("wet", pc, 2, f)]).returncode == 0
               for f in range(1, frames + 1))
# clumps: strands joined by bridges at the last frame (the checkpoint's (vertex, strand) pairs), by union-find
offs = [int(x) for x in h5(frame("wet", "cluster", 1, frames), "/patch/strand_offsets")]
def clumps(run, pc):
    pairs = h5(bake(run, pc, 1) + "/checkpoint.h5", "/hair_solver/bridges")
    strand_of = [s for s in range(len(offs) - 1) for _ in range(offs[s], offs[s + 1])]
    uf = list(range(len(offs) - 1))
    def find(x):
        while uf[x] != x:
            uf[x] = uf[uf[x]]
            x = uf[x]
        return x
    for k in range(0, len(pairs), 2):
        a, b = find(strand_of[int(pairs[k])]), find(int(pairs[k + 1]))
        if a != b: uf[max(a, b)] = min(a, b)
    size = {}
    for s in range(len(uf)): size[find(s)] = size.get(find(s), 0) + 1
    big = [v for v in size.values() if v > 1]
    return len(big), max(big) if big else 1, sum(big)
frows = list(csv.DictReader(open(fcsv)))
out = []
for line in open(g + "/runs.txt"):
    run, pc, j, wall, other, load = line.split()
    rs = [r for r in frows if r["run"] == run and r["precond"] == pc and r["threads"] == j]
    n = sum(int(r["steps"]) for r in rs)
    tot = lambda k: sum(float(r[k]) for r in rs)
    out.append(dict(run=run, precond=pc, threads=j, frames=len(rs), steps=n, wall_s=float(wall),
                    s_per_step=tot("hair_s") / n, solve_s_per_step=tot("solve_s") / n,
                    wet_s_per_step=(tot("film_s") + tot("cross_flow_s") + tot("bridges_s")) / n,
                    cg_per_step=tot("cg_iterations") / n,
                    cg_first_frame_per_step=int(rs[0]["cg_iterations"]) / int(rs[0]["steps"]),
                    not_converged=int(tot("not_converged")), bridges_mean=tot("bridges") / len(rs),
                    bridges_first_frame=int(rs[0]["bridges"]), contacts_mean=tot("contacts") / len(rs),
                    other_cpus=float(other), load=load))
def get(run, pc, j): return next(o for o in out if o["run"] == run and o["precond"] == pc and o["threads"] == j)
with open(rcsv, "w") as f:
    w = csv.DictWriter(f, fieldnames=list(out[0].keys()) + ["max_distance_to_tight_m", "identical_to_1_thread"])
    w.writeheader()
    for o in out:
        row = dict(o)
        d = {("wet", "block"): d_bt, ("wet", "cluster"): d_ct}.get((o["run"], o["precond"]))
        row["max_distance_to_tight_m"] = "%.3e" % d if d is not None and o["threads"] == "1" else ""
        row["identical_to_1_thread"] = ("yes" if identical(o["precond"]) else "no") if o["threads"] == "2" else ""
        w.writerow(row)
print("### 2. 1,024 strands × 30 vertices with cohesion: block and cluster at tolerance 1e-8")
print()
print("%d frames at 10 hair steps a frame (1/240 s); precompute %.2f s. Means per step; `tight`: block at tolerance "
      "1e-11 (the converged answer); `cohesion_off`: Cohesion.scale 0, 1 frame." % (frames, pre))
print()
print("| run | precond | threads | steps | s/step | solve | wet phases | CG it./step | first frame | not conv. | bridges | contacts | other CPUs | load |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
for o in out:
    print("| %s | %s | %s | %d | %.3f | %.3f | %.3f | %.1f | %.1f | %d | %.0f | %.0f | %.2f | %s |" % (
        o["run"], o["precond"], o["threads"], o["steps"], o["s_per_step"], o["solve_s_per_step"], o["wet_s_per_step"],
        o["cg_per_step"], o["cg_first_frame_per_step"], o["not_converged"], o["bridges_mean"], o["contacts_mean"],
        o["other_cpus"], o["load"]))
print()
b1, c1 = get("wet", "block", "1"), get("wet", "cluster", "1")
ratio = b1["cg_per_step"] / max(c1["cg_per_step"], 1e-300)
print("- cluster against block: %.0f× fewer CG iterations per step (%.1f against %.1f): %s the 3× asked for; "
      "seconds per step %.3f against %.3f on 1 thread, %.3f against %.3f on 2." % (
          ratio, c1["cg_per_step"], b1["cg_per_step"], "meets" if ratio >= 3 else "misses", c1["s_per_step"],
          b1["s_per_step"], get("wet", "cluster", "2")["s_per_step"], get("wet", "block", "2")["s_per_step"]))
print("- the same answer (largest distance of a vertex) at frame %s: cluster from block %s m; from the converged answer "
      "(tight) block %s m, cluster %s m; vertices moved up to %s m from the groom." % tuple(
          ", ".join(("%d" if k < 0 else "%.1e") % (f + 1 if k < 0 else a[k]) for f, a in enumerate(agree))
          for k in (-1, 0, 1, 2, 3)))
print("- 2 threads reproduce 1 thread bit for bit (frame caches): block %s, cluster %s." % (
    "yes" if identical("block") else "no", "yes" if identical("cluster") else "no"))
k, big, tot = clumps("wet", "cluster")
print("- clumps at frame %d (strands joined by bridges, cluster run): %d of 2 strands or more, %d strands in them, the "
      "largest %d strands (%d DOFs)." % (frames, k, tot, big, big * 119))
off, on = get("cohesion_off", "block", "1"), get("wet", "block", "1")
print("- the bridges' rows in the CG's matrix (K_G): with Cohesion.scale 0 (bridges found, %d in the first frame's last "
      "step, their rows left out) block takes %.1f CG iterations per step in the first frame, against %.1f with their "
      "rows (%d bridges)." % (off["bridges_first_frame"], off["cg_first_frame_per_step"], on["cg_first_frame_per_step"],
                               on["bridges_first_frame"]))
print()
PY
fi

# ---- 3. wet fur shot ------------------------------------------------------------------------------------------------
if [ "$part" = all ] || [ "$part" = shake ]; then
  s=$work/shake
  mkdir -p "$s"
  python3 - "$root/assets/scenes/hair_shake.json" "$s/hair_shake_wet.json" <<'PY'
import json, os, sys
src, dst = sys.argv[1], sys.argv[2]
s = json.load(open(src))
here = os.path.dirname(src)
for e in s["elements"]:
    for comp in e["components"].values():
        for k in ("scalp", "curves", "file"):
            if k in comp: comp[k] = os.path.normpath(os.path.join(here, comp[k]))
    if e["type"] == "hair":
        e["components"]["Wetting"] = {}
        e["components"]["Film"] = {"initial_ratio": 3}
s["shot"]["name"] = "hair_shake_wet"
json.dump(s, open(dst, "w"), indent=1)
PY
  res=$(timed "$s/pre.log" bin/precompute "$s/hair_shake_wet.json" --cache "$cache" --out "$s/out" -j 2) ||
    die_log "precompute of the wet hair_shake" "$s/pre.log"
  read -r spre _ <<<"$res"
  shake_csv=${base}_shake.csv
  echo "variant,frame,frame_s,hair_s,solve_s,bridges_s,film_s,cross_flow_s,cg_iterations,contacts,bridges,film_max_ratio" > "$shake_csv"
  for v in wet dry; do
    sc=$s/hair_shake_wet.json; [ $v = dry ] && sc=assets/scenes/hair_shake.json
    res=$(timed "$s/$v.log" bin/bake "$sc" --cache "$cache" --out "$s/out" -j 2 -q) ||
      die_log "bake of the $v hair_shake" "$s/$v.log"
    read -r wall other <<<"$res"
    echo "$v $wall $other $(load)" >> "$s/runs.txt"
    name=hair_shake; [ $v = wet ] && name=hair_shake_wet
    python3 - "$s/out/$name/bake/progress.jsonl" "$v" >> "$shake_csv" <<'PY'
import json, sys
for l in open(sys.argv[1]):
    r = json.loads(l)
    s = r["seconds"]
    f, c, b = s.get("film", 0.0), s.get("cross_flow", 0.0), s.get("bridges", 0.0)
    print("%s,%d,%.4f,%.4f,%.4f,%.4f,%.4f,%.4f,%d,%d,%d,%.3g" % (sys.argv[2], r["frame"], s["frame"], s["hair"],
          s["hair"] - f - c - b, b, f, c, r["hair_cg_iterations"], r["hair_contacts"], r.get("hair_bridges", 0),
          r.get("film_max_ratio", 1.0)))
PY
  done
  python3 - "$shake_csv" "$s/runs.txt" "$spre" <<'PY'
import csv, sys
rows = list(csv.DictReader(open(sys.argv[1])))
runs = {l.split()[0]: l.split()[1:] for l in open(sys.argv[2])}
print("### 3. wet fur shot: hair_shake with a film (H/r = 3) against the dry hair_shake, 2 threads")
print()
print("precompute of the wet shot: %.2f s (its cohesion tables are cache hits when part 2 built them)" % float(sys.argv[3]))
print()
print("| shot | frames | s/frame | hair solve | bridges | film | cross-hair flow | CG it./frame | contacts | bridges | wall s | other CPUs | load |")
print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
mean = {}
for v in ("wet", "dry"):
    rs = [r for r in rows if r["variant"] == v]
    m = lambda k: sum(float(r[k]) for r in rs) / len(rs)
    mean[v] = m("frame_s")
    print("| %s | %d | %.3f | %.3f | %.3f | %.4f | %.4f | %.0f | %.0f | %.0f | %s | %s | %s |" % (
        v, len(rs), m("frame_s"), m("solve_s"), m("bridges_s"), m("film_s"), m("cross_flow_s"), m("cg_iterations"),
        m("contacts"), m("bridges"), runs[v][0], runs[v][1], runs[v][2]))
print()
print("- the wet shot costs %.2f× the dry one per frame. hair solve: the hair step less its wet phases (predicting, "
      "contacts, the linear solve, committing); bridges: finding them, adding their rows and the film's load on the "
      "solve; film: the film's flow along the strands; cross-hair flow: across the bridges." % (mean["wet"] / mean["dry"]))
print()
PY
fi
echo "machine: load average $(load) at the end"
