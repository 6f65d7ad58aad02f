# PCG iterations and seconds against resolution for each preconditioner (input pcg.csv).
set datafile separator ","
set terminal pngcairo size 1000,420 noenhanced
set output "pcg.png"
set multiplot layout 1,2 title "pressure Poisson: PCG to rel_tol 1e-6"
set key top left
set logscale x 2
set xlabel "grid resolution (cells per side)"
set ylabel "iterations"
plot for [p in "mic0 jacobi none"] "< grep ,".p.", pcg.csv" using 1:4 with linespoints title p
set logscale y
set ylabel "seconds"
plot for [p in "mic0 jacobi none"] "< grep ,".p.", pcg.csv" using 1:5 with linespoints title p
unset multiplot
