# Cohesion table plots (run from out/bench/, input cohesion.csv): error of F against resolution (mean and largest
# outside the corner of touching solids, largest inside it) with a slope-2 guide, and build seconds against resolution.
set datafile separator ","
set terminal pngcairo size 1200,480 noenhanced
set output "cohesion.png"
set multiplot layout 1,2 title "cohesion tables, contact angle 40 deg: error against a central difference of the closed forms"
set logscale xy
set grid
set xtics (64, 128, 256, 512, 1024)
set xrange [50:1300]
set format y "%.0e"
set key top right font ",9"
set xlabel "table resolution (samples per axis)"
set ylabel "|F_table - F| / max(|F|, 1)"
plot "< grep '^cylinders,' cohesion.csv" using 2:6 with linespoints pt 7 title "cylinders mean", \
     "" using 2:7 with linespoints pt 6 title "cylinders max", \
     "" using 2:8 with linespoints pt 6 dt 3 title "cylinders max in the corner", \
     "< grep '^plane,' cohesion.csv" using 2:6 with linespoints pt 5 title "plane mean", \
     "" using 2:7 with linespoints pt 4 title "plane max", \
     "" using 2:8 with linespoints pt 4 dt 3 title "plane max in the corner", \
     [64:1024] 1e-4 * (256.0 / x)**2 with lines dt 2 lw 2 lc rgb "gray" title "slope -2"
set ylabel "build seconds"
set format y "%g"
set key top left
plot "< grep '^cylinders,' cohesion.csv" using 2:4 with linespoints pt 7 title "cylinders, all threads", \
     "" using 2:5 with linespoints pt 6 title "cylinders, 1 thread", \
     "< grep '^plane,' cohesion.csv" using 2:4 with linespoints pt 5 title "plane, all threads", \
     "" using 2:5 with linespoints pt 4 title "plane, 1 thread"
unset multiplot
