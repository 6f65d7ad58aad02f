# Film benchmark plots (run from out/bench/):
#   film_error.png: against the film substep δt (h = 1/24 s, desc.substeps 1 … 256): the terminal speed's relative
#     error (uniform film on a held vertical hair; exact at every δt up to round-off), the Gaussian bump's peak error
#     against 4096 substeps per step (the transient converges with δt), and the volume drift of all three cases;
#   film_cost.png: seconds per film step (load + step) of 600 strands × 15 vertices on 1 and 2 threads.
set datafile separator ","
set terminal pngcairo size 1400,520 noenhanced
set output "film_error.png"
set multiplot layout 1,2 title "film on one hair: error against the film substep (h = 1/24 s)"
set logscale xy
set format x "%.0e"
set format y "%.0e"
set grid
set key bottom right font ",9"
set xlabel "mean film substep δt (s)"
set ylabel "relative error"
set title "terminal speed (against g/c) and bump peak (against 4096 substeps)"
plot "< grep '^terminal,' film_error.csv" using 4:($6 > 0 ? $6 : 1e-17) with linespoints pt 7 title "terminal speed", \
     "< grep '^bump,' film_error.csv" using 4:($6 > 0 ? $6 : 1e-17) with linespoints pt 5 title "bump peak"
set ylabel "relative drift of volume + pools"
set title "volume"
plot "< grep '^terminal,' film_error.csv" using 4:($7 > 0 ? $7 : 1e-17) with linespoints pt 7 title "terminal (0.125 s)", \
     "< grep '^bump,' film_error.csv" using 4:($7 > 0 ? $7 : 1e-17) with linespoints pt 5 title "bump (0.25 s)", \
     "< grep '^swing,' film_error.csv" using 4:($7 > 0 ? $7 : 1e-17) with linespoints pt 9 title "swing (2 s)"
unset multiplot

reset
set datafile separator ","
set terminal pngcairo size 700,420 noenhanced
set output "film_cost.png"
set style data histograms
set style fill solid 0.8 border -1
set boxwidth 0.6
set grid ytics
set yrange [0:*]
set ylabel "seconds per film step (load + step)"
set title "600 strands x 15 vertices, h = 1/240 s"
plot "film.csv" every ::1 using 6:xtic(sprintf("%d thread(s)", int($3))) notitle
