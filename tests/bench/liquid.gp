# Liquid benchmark plots (run from out/bench/): seconds per substep of each phase against the grid
# resolution (liquid.csv), and run time against the error of the dam-break front (liquid_error.csv).
set datafile separator ","
set terminal pngcairo size 1000,420 noenhanced

set output "liquid_phases.png"
set title "liquid dam break: seconds per substep by phase"
set key top left
set logscale xy
set xlabel "grid resolution (cells per side)"
set ylabel "seconds per substep"
set xrange [28:110]
set xtics (32, 48, 64, 96)
plot "liquid.csv" using 1:4 skip 1 with linespoints lw 2 title "total", \
     "" using 1:5 skip 1 with linespoints title "P2G", \
     "" using 1:6 skip 1 with linespoints title "pressure", \
     "" using 1:7 skip 1 with linespoints title "G2P", \
     "" using 1:8 skip 1 with linespoints title "advect", \
     "" using 1:9 skip 1 with linespoints title "other"

set output "liquid_error.png"
set title "dam-break front (99th percentile of x) at t = 0.25 s: run time vs error against 64 cells/m"
set autoscale x
unset xtics
set xtics auto
set xlabel "absolute error of the front position (m)"
set ylabel "seconds (10 frames)"
# the reference itself has zero error and is left out of the log plot
plot "liquid_error.csv" using ($7 > 0 ? $7 : 1/0):5:(sprintf("%d/m", $1)) skip 1 with labels offset 0,1 notitle, \
     "" using ($7 > 0 ? $7 : 1/0):5 skip 1 with linespoints pt 7 title "16, 24, 32, 48 cells/m"
