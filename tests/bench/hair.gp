# Hair benchmark plots (run from out/bench/):
#   hair_cost.png: seconds per step split into groups / contact / solve for every configuration of hair.csv
#     (1,024 and 10,000 strands), and CG iterations per step against the cap;
#   hair_error.png: run time against the tips' RMS error at the end (hair_error.csv): the Δt sweep at tol 1e-12
#     and the tolerance sweep at Δt = 1/240 s for each preconditioner; and the solver's own error (against
#     tol 1e-12 at the same Δt) against the tolerance. Only runs that finished (status ok) are drawn.
#   hair_springs.png: strands joined by springs along their length (hair_springs.csv): CG iterations and seconds
#     per step against the spring stiffness, block and cluster, for the bundle and the clumps, on 1 and 2 threads.
set datafile separator ","
set terminal pngcairo size 1500,900 noenhanced

# ---- hair_cost.png ------------------------------------------------------------------------------------------
set output "hair_cost.png"
set multiplot layout 2,2 title "hair step with hair-hair contact (tol 1e-8, cap 5000): mean per step"
set style data histograms
set style histogram rowstacked
set style fill solid 0.8 border -1
set boxwidth 0.8
set key inside top center horizontal font ",9"
set offsets 0, 0, graph 0.15, 0  # headroom for the key
set grid ytics
set xtics rotate by -45 font ",8"
set ylabel "seconds per step"
label(c4, c5, c6) = sprintf("%s %s %dt", c4, c5, c6)
set title "1024 strands x 30 vertices"
plot "< grep '^1024,' hair.csv" using 11:xtic(label(strcol(4), strcol(5), int($6))) title "groups", \
     "" using 12 title "contact search + K_G", "" using 13 title "factor + PCG"
set title "10000 strands x 30 vertices"
plot "< grep '^10000,' hair.csv" using 11:xtic(label(strcol(4), strcol(5), int($6))) title "groups", \
     "" using 12 title "contact search + K_G", "" using 13 title "factor + PCG"
set style histogram clustered gap 1
set offsets 0, 0, 0, 0
set logscale y
set yrange [1:20000]
set ylabel "CG iterations per step (5000 = cap: not converged)"
set title "1024 strands: CG iterations per step"
plot "< grep '^1024,' hair.csv" using 14:xtic(label(strcol(4), strcol(5), int($6))) notitle
set title "10000 strands: CG iterations per step"
plot "< grep '^10000,' hair.csv" using 14:xtic(label(strcol(4), strcol(5), int($6))) notitle
unset multiplot

# ---- hair_error.png -----------------------------------------------------------------------------------------
reset
set datafile separator ","
set terminal pngcairo size 1400,560 noenhanced
set output "hair_error.png"
set multiplot layout 1,2 title "shaking scalp with hair-hair contact: error of the strand tips at the end"
set logscale xy
set format x "%.0e"
set grid
set key top right font ",9"
set xlabel "tip RMS error against the reference (m)"
set ylabel "seconds (1 thread)"
set title "run time against error (reference: block, tol 1e-12, dt 1/7680 s)"
plot "< grep '^dt,block,ok,' hair_error.csv" using ($11 > 0 ? $11 : 1/0):10 with linespoints pt 7 title "dt sweep (tol 1e-12)", \
     "" using ($11 > 0 ? $11 : 1/0):10:(sprintf("1/%d", $4)) with labels offset 0,0.8 font ",8" notitle, \
     "< grep '^tol,block,ok,' hair_error.csv" using 11:10 with linespoints pt 5 title "tol sweep, block (dt 1/240)", \
     "< grep '^tol,jacobi,ok,' hair_error.csv" using 11:10 with linespoints pt 9 title "tol sweep, jacobi", \
     "< grep '^tol,none,ok,' hair_error.csv" using 11:10 with linespoints pt 11 title "tol sweep, none", \
     "< grep '^tol,cluster,ok,' hair_error.csv" using 11:10 with linespoints pt 13 title "tol sweep, cluster"
set xlabel "tolerance (relative mass-weighted residual)"
set ylabel "tip error against tol 1e-12 at dt 1/240 s (m)"
set format y "%.0e"
set title "the solver's own error at dt 1/240 s"
set key bottom right
plot "< grep '^tol,block,ok,' hair_error.csv" using 6:13 with linespoints pt 5 title "block RMS", \
     "" using 6:14 with linespoints pt 4 dt 2 title "block max", \
     "< grep '^tol,jacobi,ok,' hair_error.csv" using 6:13 with linespoints pt 9 title "jacobi RMS", \
     "< grep '^tol,none,ok,' hair_error.csv" using 6:13 with linespoints pt 11 title "none RMS", \
     "< grep '^tol,cluster,ok,' hair_error.csv" using 6:13 with linespoints pt 13 title "cluster RMS"
unset multiplot

# ---- hair_springs.png -----------------------------------------------------------------------------------------
reset
set datafile separator ","
set terminal pngcairo size 1400,900 noenhanced
set output "hair_springs.png"
set multiplot layout 2,2 title "1024 strands x 30 vertices joined by springs at every vertex, dt 1e-3 s, tol 1e-8: mean per step"
set logscale x
set grid
set key top left font ",9"
set xlabel "spring stiffness (N/m)"
do for [layout in "bundle clumps"] {
  file = layout eq "bundle" ? "< grep '^bundle' hair_springs.csv" : "< grep '^64 clumps' hair_springs.csv"
  set title (layout eq "bundle" ? "one bundle of 32 x 32" : "64 clumps of 4 x 4")." : CG iterations per step"
  set logscale y
  set ylabel "CG iterations per step"
  plot file using ($7 == 1 && strcol(6) eq "block" ? $4 : 1/0):($13 > 0 ? $13 : 0.5) with linespoints pt 5 title "block", \
       file using ($7 == 1 && strcol(6) eq "cluster" ? $4 : 1/0):($13 > 0 ? $13 : 0.5) with linespoints pt 7 title "cluster"
  set title (layout eq "bundle" ? "one bundle of 32 x 32" : "64 clumps of 4 x 4")." : seconds per step"
  set ylabel "seconds per step"
  plot file using ($7 == 1 && strcol(6) eq "block" ? $4 : 1/0):10 with linespoints pt 5 title "block, 1 thread", \
       file using ($7 == 2 && strcol(6) eq "block" ? $4 : 1/0):10 with linespoints pt 4 dt 2 title "block, 2 threads", \
       file using ($7 == 1 && strcol(6) eq "cluster" ? $4 : 1/0):10 with linespoints pt 7 title "cluster, 1 thread", \
       file using ($7 == 2 && strcol(6) eq "cluster" ? $4 : 1/0):10 with linespoints pt 6 dt 2 title "cluster, 2 threads"
}
unset multiplot
