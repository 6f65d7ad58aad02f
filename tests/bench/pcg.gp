# PCG iterations and seconds (setup included) against resolution for each preconditioner and thread count
# (input pcg.csv: resolution,unknowns,preconditioner,threads,iterations,seconds,setup_seconds,solve_seconds,...).
set datafile separator ","
set terminal pngcairo size 1000,420 noenhanced
set output "pcg.png"
set multiplot layout 1,2 title "pressure Poisson (tank): PCG to rel_tol 1e-6"
set key top left
set logscale x 2
set xlabel "grid resolution (cells per side)"
set ylabel "iterations"
plot for [p in "multigrid mic0"] for [t in "1 2"] "< grep ,".p.",".t.", pcg.csv" using 1:5 with linespoints \
       title p." ".t." thread(s)", \
     for [p in "jacobi none"] "< grep ,".p.", pcg.csv" using 1:5 with linespoints title p
set logscale y
set ylabel "seconds (setup + solve)"
plot for [p in "multigrid mic0"] for [t in "1 2"] "< grep ,".p.",".t.", pcg.csv" using 1:6 with linespoints \
       title p." ".t." thread(s)", \
     for [p in "jacobi none"] "< grep ,".p.", pcg.csv" using 1:6 with linespoints title p
unset multiplot
