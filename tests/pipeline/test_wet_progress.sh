# Wet hair's figures per frame in progress.jsonl: the two-strand scene cylinder_2 (bridged along their length,
# film flowing between them) baked for 4 frames; every line carries the bridges and the film's flow across them,
# and the wet phases' seconds as separate keys (film along the strands, cross_flow across the bridges, bridges),
# each a part of the hair step's seconds (their sum within seconds.hair: measured inside it, never overlapping).
source "$(dirname "$0")/lib.sh"
scene="$ROOT/assets/scenes/cylinder_2.json"
bd="$DRENCH_OUT/cylinder_2/bake"
"$BIN/precompute" "$scene" -q >"$WORK/precompute.log" 2>&1
"$BIN/bake" "$scene" --frames 1-4 -j 2 -q >"$WORK/bake.log" 2>&1
check "cylinder_2 bakes 4 frames" bash -c "[ \$(wc -l < '$bd/progress.jsonl') -eq 4 ]"
check "every frame of wet hair reports its phases film, cross_flow and bridges within the hair's seconds" \
  python3 - "$bd/progress.jsonl" <<'PY'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
ok = len(rows) == 4
for r in rows:
    s = r["seconds"]
    parts = [s.get(k) for k in ("film", "cross_flow", "bridges")]
    ok = ok and all(isinstance(p, float) and p >= 0 for p in parts) and sum(parts) <= s["hair"]
    ok = ok and r["hair_bridges"] > 0 and r["film_cross_flow"] > 0
sys.exit(0 if ok else 1)
PY
