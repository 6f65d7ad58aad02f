# Frame-parallel meshing and the mesh stage's particle caches: mesh -j 2 meshes two frames at a time and writes the
# same bytes as -j 1 (OBJ, surface VDB, points VDB) for a liquid with a collider, an MPM solid and hair; every
# frame of every liquid, MPM solid and hair element gets <element>.NNNN.points.vdb (vdb_print reads it), and
# mesh --finish misses none; mesh.velocity_interior fills "vel" inside the surface; mesh.write_points false
# writes none.
source "$(dirname "$0")/lib.sh"

# bake once per scene, then mesh the same frames with -j 1 and -j 2 into two output roots sharing that bake
mesh_twice() { # NAME SCENE LAST
  local name="$1" scene="$2" last="$3"
  "$BIN/bake" "$scene" --frames "1-$last" --out "$WORK/j1" -q -j 2 >/dev/null 2>&1 || { fail "$name: bake" "bake failed"; return 1; }
  mkdir -p "$WORK/j2/$name"
  cp -r "$WORK/j1/$name/bake" "$WORK/j2/$name/"
  "$BIN/mesh" "$scene" --frames "1-$last" --out "$WORK/j1" -j 1 >"$WORK/$name.j1.log" 2>&1 || { fail "$name: mesh -j 1" "$(tail -2 "$WORK/$name.j1.log")"; return 1; }
  "$BIN/mesh" "$scene" --frames "1-$last" --out "$WORK/j2" -j 2 >"$WORK/$name.j2.log" 2>&1 || { fail "$name: mesh -j 2" "$(tail -2 "$WORK/$name.j2.log")"; return 1; }
}
same_files() { # NAME: every file of the two mesh folders, byte for byte (the MANIFEST holds the time)
  local a="$WORK/j1/$1/mesh" b="$WORK/j2/$1/mesh" f n=0
  [ "$(ls "$a" | sort)" = "$(ls "$b" | sort)" ] || { echo "different file lists"; return 1; }
  for f in "$a"/*; do [ "$(basename "$f")" = MANIFEST ] && continue; cmp -s "$f" "$b/$(basename "$f")" || { echo "differs: $(basename "$f")"; return 1; }; n=$((n + 1)); done
  echo "$n files identical"
}

for spec in "small_dam $ROOT/assets/scenes/small_dam.json 6 water" "mpm_drop $ROOT/tests/data/mpm_drop.json 4 jelly" \
            "hair_small $ROOT/tests/data/hair_small.json 8 -"; do
  set -- $spec
  name=$1 scene=$2 last=$3 element=$4
  mesh_twice "$name" "$scene" "$last" || continue
  check "$name: mesh -j 2 meshes two frames at a time" grep -q "frames in .* (2 at a time)" "$WORK/$name.j2.log"
  check "$name: mesh -j 1 meshes one frame at a time" grep -q "frames in .* (1 at a time)" "$WORK/$name.j1.log"
  check "$name: -j 1 and -j 2 write the same files, byte for byte" same_files "$name"
  if [ "$element" != "-" ]; then
    check "$name: a points file per frame" test "$(ls "$WORK/j2/$name/mesh/$element".[0-9][0-9][0-9][0-9].points.vdb | wc -l)" -eq "$last"
  fi
done
hair_points=$(ls "$WORK/j2/hair_small/mesh/"*.points.vdb 2>/dev/null | wc -l)
check "hair_small: a points file per frame" test "$hair_points" -eq 8

# vdb_print (Debian's openvdb-tools) reads the points grid
pts="$WORK/j2/small_dam/mesh/water.0006.points.vdb"
if command -v vdb_print >/dev/null 2>&1; then
  vdb_print -l -m "$pts" >"$WORK/vdb_print.txt" 2>&1
  check "vdb_print lists the points grid of water.0006.points.vdb" \
    bash -c "grep -q '^Name: points' '$WORK/vdb_print.txt' && grep -q ptdataidx32 '$WORK/vdb_print.txt'"
  check "vdb_print shows the file metadata of the points" \
    bash -c "grep -q 'up_axis: y' '$WORK/vdb_print.txt' && grep -q 'frame: 6' '$WORK/vdb_print.txt'"
else
  echo "SKIP vdb_print checks (vdb_print not installed)"
fi

# mesh --finish wants every points file (hair_small: the whole shot was meshed)
check "mesh --finish passes with every points file" "$BIN/mesh" "$ROOT/tests/data/hair_small.json" --finish --out "$WORK/j2" -q
hair_pts=$(ls "$WORK/j2/hair_small/mesh/"*.0003.points.vdb | head -1)
rm -f "$hair_pts"
expect_exit "mesh --finish names a missing points file" 2 "$(basename "$hair_pts")" \
  "$BIN/mesh" "$ROOT/tests/data/hair_small.json" --finish --out "$WORK/j2"

# mesh.velocity_interior: "vel" covers the liquid inside the surface (more active voxels than the surface's band) in
# frame 1, where the column of water is deeper than the band (by frame 6 it has spread thinner than the band)
active() { vdb_print -l "$1" 2>/dev/null | awk -v g="$2" '/^Name:/ {cur = $2} cur == g && /Number of active voxels/ {gsub(",", "", $NF); print $NF}'; }
vi_scene=$(stage_scene small_dam.json) # a copy beside its meshes: the bake key is the same
sed -i 's/"mesh": { "smoothing": 1 }/"mesh": { "smoothing": 1, "velocity_interior": true, "write_points": false }/' \
  "$vi_scene"
mkdir -p "$WORK/vi/out/small_dam"
cp -r "$WORK/j1/small_dam/bake" "$WORK/vi/out/small_dam/"
if "$BIN/mesh" "$vi_scene" --frames 1-6 --out "$WORK/vi/out" -q >"$WORK/vi.log" 2>&1; then
  if command -v vdb_print >/dev/null 2>&1; then
    band_s=$(active "$WORK/j1/small_dam/mesh/water.0001.vdb" surface); band_v=$(active "$WORK/j1/small_dam/mesh/water.0001.vdb" vel)
    in_s=$(active "$WORK/vi/out/small_dam/mesh/water.0001.vdb" surface); in_v=$(active "$WORK/vi/out/small_dam/mesh/water.0001.vdb" vel)
    echo "vel voxels: band $band_v (surface $band_s), with velocity_interior $in_v (surface $in_s)"
    check "by default vel has the surface's band" test "$band_v" -eq "$band_s"
    check "velocity_interior: the same surface, vel on more voxels than the band" bash -c "[ '$in_s' -eq '$band_s' ] && [ '$in_v' -gt '$band_v' ]"
  fi
  check "velocity_interior keeps the OBJ" cmp -s "$WORK/j1/small_dam/mesh/water.0001.obj" "$WORK/vi/out/small_dam/mesh/water.0001.obj"
  check "write_points false writes no points" test "$(ls "$WORK/vi/out/small_dam/mesh/" | grep -c points)" -eq 0

else
  fail "velocity_interior mesh" "$(tail -2 "$WORK/vi.log")"
fi
