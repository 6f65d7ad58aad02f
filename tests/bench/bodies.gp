# Bodies in the projection (run from out/bench/; tests/bench/bench_bodies writes bodies.csv): a held sphere's
# buoyancy error against Archimedes and the wall seconds of twelve substeps, against cells per radius.
set datafile separator ","
set terminal pngcairo size 1400,560 noenhanced
set output "bodies.png"
set multiplot layout 1,2 title "a sphere held in still water: buoyancy error and cost against resolution, 2 threads"
set grid
set key top right font ",9"
set logscale xy
set xlabel "cells per radius"
set title "|force / (rho g V) - 1|"
plot "< grep '^ghost_fluid,' bodies.csv" using 3:5 with linespoints pt 5 title "ghost fluid", \
     "< grep '^mass_weighted,' bodies.csv" using 3:5 with linespoints pt 7 title "mass weighted"
set title "wall seconds (12 substeps)"
plot "< grep '^ghost_fluid,' bodies.csv" using 3:6 with linespoints pt 5 title "ghost fluid", \
     "< grep '^mass_weighted,' bodies.csv" using 3:6 with linespoints pt 7 title "mass weighted"
unset multiplot
