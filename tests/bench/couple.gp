# Coupled hair–fluid benchmark plot (run from out/bench/; tests/bench/bench_couple.sh writes couple.csv): for fur_tank
# (liquid), fur_wind (air) and dragging_test with Drag (liquid, the reference code's scene), against
# solver.coupling_iterations 1–5: wall seconds per clock step (2 threads; the reference code's 2.0 s per 0.004 s step on
# dragging_test as a line) and the largest final relative change of a step.
set datafile separator ","
set terminal pngcairo size 1400,560 noenhanced
set output "couple.png"
set multiplot layout 1,2 title "hair coupled with a fluid (Drag): cost and convergence against coupling iterations, 2 threads"
set grid
set key bottom right font ",9"
set xlabel "solver.coupling_iterations (coupling_tolerance 1e-12)"
set xtics 1
set xrange [0.7:5.3]
set title "wall seconds per clock step"
set ylabel "s per step"
set logscale y
set yrange [0.03:4]
plot "< grep '^fur_tank,' couple.csv | sort -t, -k2,2n" using 2:5 with linespoints pt 5 title "fur_tank (300 strands, 46k particles)", \
     "< grep '^fur_wind,' couple.csv | sort -t, -k2,2n" using 2:5 with linespoints pt 7 title "fur_wind (300 strands, air 24x20x16)", \
     "< grep '^dragging_test,' couple.csv | sort -t, -k2,2n" using 2:5 with linespoints pt 9 title "dragging_test + Drag (1 strand, 119k particles)", \
     2.0 with lines dt 2 lw 2 title "reference code, dragging_test (2.0 s per 0.004 s step)"
set title "largest final relative change of a step"
set ylabel "relative change"
set yrange [1e-10:100]
set format y "%.0e"
set key top right font ",9"
plot "< grep '^fur_tank,' couple.csv | sort -t, -k2,2n" using 2:8 with linespoints pt 5 title "fur_tank", \
     "< grep '^fur_wind,' couple.csv | sort -t, -k2,2n" using 2:8 with linespoints pt 7 title "fur_wind", \
     "< grep '^dragging_test,' couple.csv | sort -t, -k2,2n" using 2:8 with linespoints pt 9 title "dragging_test + Drag", \
     1e-3 with lines dt 3 title "default coupling_tolerance (1e-3)"
unset multiplot
