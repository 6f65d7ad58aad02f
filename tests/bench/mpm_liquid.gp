# MPM solids two-way with the liquid against resolution (run from out/bench/; tests/bench/bench_mpm_liquid.sh writes
# mpm_liquid.csv): relative error of the sinking ball's first-frame acceleration (against potential flow) and of the
# floating ball's submerged fraction (against ½), against the bake's seconds.
set datafile separator ","
set terminal pngcairo size 900,560 noenhanced
set output "mpm_liquid.png"
set grid
set logscale xy
set key top right font ",9"
set xlabel "bake seconds (2 threads)"
set ylabel "relative error"
set title "MPM ball two-way with water: error against run time (dx 0.04 ... 0.0125 m)"
plot "< grep '^sink,' mpm_liquid.csv" using 5:($7 > 0 ? $7 : 1e-5) with linespoints pt 5 title "sink: first-frame acceleration", \
     "< grep '^float,' mpm_liquid.csv" using 5:($7 > 0 ? $7 : 1e-5) with linespoints pt 7 title "float: submerged fraction"
