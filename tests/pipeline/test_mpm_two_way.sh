#!/usr/bin/env bash
# MPM solids two-way with the liquid (Integrator.liquid_coupling "two_way", the default with a liquid):
# tests/data/mpm_dam.json breaks a 0.25 × 0.3 m dam of water on a soft jelly cube (E = 50 kPa, 1100 kg/m³, 12 cm,
# 1728 particles) held at its base by the MPM grid's no-slip floor. The wave squeezes and shears the jelly (its elastic
# energy rises, then rings down), the jelly deflects the flow (the liquid differs from the same bake with the jelly
# "none", which the water passes through), the frames carry the liquid's impulse on the solids, and the bake is
# bit-identical on 1 and 2 threads and when resumed. A scene coupling hair (Drag) and MPM solids with the liquid at
# once is refused.
source "$(dirname "$0")/lib.sh"
scene="$ROOT/tests/data/mpm_dam.json"
S="$WORK/scenes"; mkdir -p "$S"
sed 's#"MpmMaterial"#"Integrator": { "liquid_coupling": "none" }, "MpmMaterial"#; s#"name": "mpm_dam"#"name": "mpm_dam"#' "$scene" > "$S/none.json"
fr() { printf "%s/mpm_dam/bake/frame.%04d.h5" "$1" "$2"; }

b1="$WORK/b1"; b2="$WORK/b2"; b3="$WORK/b3"; b4="$WORK/b4"
t=$EPOCHREALTIME
out=$("$BIN/bake" "$scene" -j 2 --out "$b2" 2>&1); rc=$?
awk -v a="$t" -v b="$EPOCHREALTIME" 'BEGIN{printf "bake of 14 frames took %.1fs\n", b-a}'
[ "$rc" -eq 0 ] || echo "$out" | tail -5
baked() { [ "$rc" -eq 0 ] && [ "$(ls "$b2"/mpm_dam/bake/frame.*.h5 2>/dev/null | wc -l)" -eq 14 ]; }
check "bake exits 0 and writes 14 frame caches" baked
# the stability watches count the work the liquid and the solids do on each other: no alarm
check "the bake warns of nothing (the watches count the work liquid and solids do on each other)" bash -c "! grep -qi warning <<<\"\$1\"" _ "$out"

rings() { # the elastic energy: its most before the wave arrives (frames 2-4), its peak as the wave hits, its last
  local f e s=""
  for f in $(seq 2 14); do e=$(h5 "$(fr "$b2" "$f")" /diagnostics/jelly/elastic_energy); s="$s $e"; done
  echo "elastic energy per frame 2-14 (J):$s"
  awk -v s="$s" 'BEGIN { n = split(s, e, " "); lo = 0; for (i = 1; i <= 3; i++) if (e[i] > lo) lo = e[i]
    peak = 0; at = 0; for (i = 4; i <= n; i++) if (e[i] > peak) { peak = e[i]; at = i }
    printf "before the wave at most %.4g J, peak %.4g J (frame %d), last %.4g J\n", lo, peak, at + 1, e[n]
    exit !(peak > 1.5 * lo && e[n] < 0.5 * peak) }'
}
check "the wave deforms the jelly and the deformation rings down" rings
ledger() { # the impulse the liquid gave the solids is in every frame's diagnostics, downstream once the wave hits
  local j; j=$(h5 "$(fr "$b2" 5)" /diagnostics/mpm_liquid_impulse)
  echo "frame 5: liquid impulse on the MPM solids ($j) N s"
  awk -v J="$j" 'BEGIN { split(J, v, " "); exit !(v[1] > 0.01) }'
}
check "frames carry the liquid's impulse on the MPM solids" ledger

# with "none" the water passes through the jelly, which stays put
"$BIN/bake" "$S/none.json" -j 2 --out "$b4" -q >/dev/null 2>&1
mean_x() { h5 "$1" /water/position | awk '{ s = 0; for (i = 1; i <= NF; i += 3) s += $i; printf "%.6f", s / (NF / 3) }'; }
deflects() {
  local a b
  a=$(mean_x "$(fr "$b2" 14)"); b=$(mean_x "$(fr "$b4" 14)")
  echo "frame 14: the water's mean x $a m two-way, $b m with liquid_coupling none"
  awk -v a="$a" -v b="$b" 'BEGIN { d = a - b; if (d < 0) d = -d; exit !(d > 0.003) }'
}
check "the jelly deflects the flow (the water differs from the uncoupled bake's)" deflects
check "with liquid_coupling none the frames carry no MPM impulse" bash -c "! h5ls '$(fr "$b4" 5)/diagnostics' | grep -q mpm_liquid_impulse"

"$BIN/bake" "$scene" -j 1 --out "$b1" -q >/dev/null 2>&1
check "the two-way bake is bit-identical on 1 and 2 threads" same_frames "$b1" "$b2" mpm_dam 14
"$BIN/bake" "$scene" -j 2 --frames 1-7 --out "$b3" -q >/dev/null 2>&1
"$BIN/bake" "$scene" -j 2 --out "$b3" --resume >"$WORK/resume.log" 2>&1
check "the bake resumes after frame 7" grep -q "resuming after frame 7" "$WORK/resume.log"
check "a resumed two-way bake is bit-identical to an uninterrupted one" same_frames "$b2" "$b3" mpm_dam 14

# hair with Drag and two-way MPM solids in one scene: exit 2 naming the fields and the fix, no frame
python3 - "$ROOT/assets/scenes/fur_tank.json" "$scene" "$S/both.json" "$ROOT" <<'PY'
import json, sys
fur = json.load(open(sys.argv[1])); dam = json.load(open(sys.argv[2])); root = sys.argv[4]
for e in fur["elements"]:
    for c in e["components"].values():
        for k in ("scalp", "file"):
            if k in c: c[k] = root + "/assets/meshes/" + c[k].split("/")[-1]
jelly = [e for e in dam["elements"] if e["type"] == "mpm_solid"][0]
jelly["components"]["Domain"]["box"] = [[0, 0, 0], [0.3, 0.2, 0.16]]
jelly["components"]["MpmShape"]["box"] = [[0.2, 0.13, 0.05], [0.26, 0.19, 0.11]]
fur["elements"].append(jelly); fur["shot"]["name"] = "both"
json.dump(fur, open(sys.argv[3], "w"))
PY
expect_exit "hair with Drag and two-way MPM solids in one scene" 2 \
  "Integrator\.liquid_coupling.*\"none\".*Drag" "$BIN/bake" "$S/both.json" --out "$WORK/both"
check "and writes no frame" bash -c "! ls '$WORK'/both/both/bake/frame.*.h5 >/dev/null 2>&1"
