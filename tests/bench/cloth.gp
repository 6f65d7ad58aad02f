# bench_cloth plots (run from out/bench/):
#   cloth_cantilever.png: the cantilever's run time against its error (cloth_cantilever.csv), both bending models on
#     both quad-split meshes (labels: vertices along);
#   cloth_factor.png: one panel's step matrix factored by banded Cholesky and by CHOLMOD against the panel's vertices
#     (cloth_factor.csv), with CHOLMOD's analysis added and both solves.
set terminal pngcairo size 800,500 noenhanced
set datafile separator ','
set key autotitle columnhead
set logscale xy
set format xy '%g'

# ---- cloth_cantilever.png ---------------------------------------------------------------------------------------
set output 'cloth_cantilever.png'
set key bottom left
set xlabel 'wall seconds (one thread)'
set ylabel '|tip / Kirchhoff - 1|'
set title 'Cantilever plate under its weight: error against run time (labels: vertices along)'
sel(b, p, v) = (strcol(1) eq b && strcol(2) eq p) ? v : 1/0
plot 'cloth_cantilever.csv' using (sel('shape_operator', 'parallel', $7)):10 with linespoints title 'shape operator, parallel', \
     '' using (sel('shape_operator', 'parallel', $7)):10:3 with labels offset 1,1 notitle, \
     '' using (sel('shape_operator', 'alternating', $7)):10 with linespoints title 'shape operator, alternating', \
     '' using (sel('hinge', 'parallel', $7)):10 with linespoints title 'hinge, parallel', \
     '' using (sel('hinge', 'parallel', $7)):10:3 with labels offset 1,1 notitle, \
     '' using (sel('hinge', 'alternating', $7)):10 with linespoints title 'hinge, alternating'

# ---- cloth_factor.png -------------------------------------------------------------------------------------------
set output 'cloth_factor.png'
set key top left
set xlabel 'panel vertices (n x n, 3 DOFs each)'
set ylabel 'seconds (median of 5, one thread)'
set title 'One panel step matrix: banded Cholesky (RCM order) against CHOLMOD (AMD)'
plot 'cloth_factor.csv' using 2:6 with linespoints lw 2 title 'banded factor (dpbtrf)', \
     '' using 2:10 with linespoints lw 2 title 'CHOLMOD factor', \
     '' using 2:($9 + $10) with linespoints dt 2 title 'CHOLMOD analyse + factor', \
     '' using 2:7 with linespoints dt 3 title 'banded solve', \
     '' using 2:11 with linespoints dt 3 title 'CHOLMOD solve', \
     '' using 2:6:1 with labels offset 0,1 notitle
