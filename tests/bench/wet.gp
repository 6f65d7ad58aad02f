# Wet hair benchmark plots (run from out/bench/; tests/bench/bench_wet.sh writes the CSVs):
#   wet_groom.png: 1,024 wet strands x 30 vertices with cohesion: CG iterations per step in each frame for block and
#     cluster (and block with the bridges' rows left out, Cohesion.scale 0), and seconds per step of every run split
#     into the hair solve and the wet phases (wet_groom_frames.csv, wet_groom.csv).
#   wet_shake.png: the wet hair_shake's seconds per frame stacked by phase (hair solve, bridges, film, cross-hair flow)
#     with the dry hair_shake's seconds per frame beside them; CG iterations and bridges per frame (wet_shake.csv).
set datafile separator ","
set terminal pngcairo size 1400,560 noenhanced

# ---- wet_groom.png ----------------------------------------------------------------------------------------------
set output "wet_groom.png"
set multiplot layout 1,2 title "1024 wet strands x 30 vertices with cohesion (film H/r = 3), dt 1/240 s, tol 1e-8"
set grid
set key top right font ",9"
set logscale y
set xlabel "frame"
set ylabel "CG iterations per step (mean over the frame)"
set title "CG iterations per step"
set xtics 1
set yrange [0.5:5000]
set offsets 0.2, 0.2, 0, 0
plot "< grep '^wet,block,1,' wet_groom_frames.csv" using 4:($6 / $5) with linespoints pt 5 title "block", \
     "< grep '^tight,block,1,' wet_groom_frames.csv" using 4:($6 / $5) with linespoints pt 4 dt 2 title "block, tol 1e-11", \
     "< grep '^wet,cluster,1,' wet_groom_frames.csv" using 4:($6 > 0 ? $6 / $5 : 0.5) with linespoints pt 7 title "cluster", \
     "< grep '^cohesion_off,block,' wet_groom_frames.csv" using 4:($6 / $5) with points pt 9 ps 1.5 title "block, bridges out of the solve"
unset logscale y
set yrange [*:*]
unset xlabel
set style data histograms
set style histogram rowstacked
set style fill solid 0.8 border -1
set boxwidth 0.7
set offsets 0, 0, graph 0.15, 0
set xtics rotate by -30 font ",9"
set ylabel "seconds per step"
set title "seconds per step"
plot "wet_groom.csv" using 8:xtic(sprintf("%s %s %st", strcol(1), strcol(2), strcol(3))) skip 1 title "hair solve", \
     "" using 9 skip 1 title "wet phases (bridges, film, cross-hair flow)"
unset multiplot

# ---- wet_shake.png ----------------------------------------------------------------------------------------------
reset
set datafile separator ","
set terminal pngcairo size 1400,900 noenhanced
set output "wet_shake.png"
set multiplot layout 2,1 title "hair_shake (600 strands x 15 vertices on a shaken ball), 2 threads: wet (film H/r = 3) and dry"
set style data histograms
set style histogram rowstacked
set style fill solid 0.8 border -1
set boxwidth 0.8
set grid ytics
set key outside right top font ",9"
set xtics 4 font ",9"
set xlabel "frame"
set ylabel "seconds per frame"
set title "seconds per frame by phase"
plot "< grep '^wet,' wet_shake.csv" using 5:xtic(int($2) % 4 == 0 ? stringcolumn(2) : "") title "hair solve (wet)", \
     "" using 6 title "bridges", "" using 7 title "film", "" using 8 title "cross-hair flow", \
     "< grep '^dry,' wet_shake.csv" using ($2 - 1):4 with linespoints lw 2 pt 7 ps 0.6 lc rgb "black" title "dry hair_shake: hair"
set style data linespoints
set xtics 4
set ylabel "CG iterations per frame"
set y2label "bridges (last step of the frame)"
set y2tics
set ytics nomirror
set title "solver work per frame"
plot "< grep '^wet,' wet_shake.csv" using 2:9 pt 7 ps 0.6 title "CG iterations, wet", \
     "< grep '^dry,' wet_shake.csv" using 2:9 pt 5 ps 0.6 title "CG iterations, dry", \
     "< grep '^wet,' wet_shake.csv" using 2:11 axes x1y2 pt 9 ps 0.6 title "bridges, wet"
unset multiplot
