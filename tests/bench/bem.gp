# BEM benchmark plots (run from out/bench/):
#   bem.png: precompute seconds (quadrature, inverse, compression, total) and peak memory against the vertex count;
#   bem_compression.png: storage of the matrix set, the error of H_1 and of its product, and the seconds of one
#   product, of 12 products and of a body's unconstrained step against the compression ratio, on 1 and 2 threads.
set datafile separator ","
set terminal pngcairo size 1400,600 noenhanced
set key top left
set grid

set output "bem.png"
set multiplot layout 1,2 title "BEM precompute against N (boxes, n_max 5, 32x)"
set logscale xy
set xlabel "vertices"
set ylabel "seconds"
plot "bem.csv" every ::1 using 1:4 with linespoints title "quadrature + CQ weights", \
     "" every ::1 using 1:5 with linespoints title "H0^-1, H0^-1 G'", \
     "" every ::1 using 1:6 with linespoints title "compression", \
     "" every ::1 using 1:7 with linespoints lw 2 title "total"
set ylabel "MB"
plot "bem.csv" every ::1 using 1:8 with linespoints title "peak resident", \
     "" every ::1 using 1:9 with linespoints title "dense set", \
     "" every ::1 using 1:10 with linespoints title "compressed set"
unset multiplot

set output "bem_compression.png"
set multiplot layout 1,3 title "BEM compression (vertex order + xyz blocks + 2-D Haar)"
set logscale xy
set xlabel "compression ratio"
set ylabel "relative error"
plot "< awk -F, 'NR>1 && $8==1 && $1>1' bem_compression.csv" using 1:5 with linespoints title "H_1 (Frobenius)", \
     "" using 1:6 with linespoints title "H_1 x, smooth x", "" using 1:7 with linespoints title "H_1 x, random x"
set ylabel "MB"
plot "< awk -F, 'NR>1 && $8==1' bem_compression.csv" using 1:4 with linespoints title "matrix set"
set ylabel "seconds"
plot "< awk -F, 'NR>1 && $8==1' bem_compression.csv" using 1:9 with linespoints title "one product, 1 thread", \
     "< awk -F, 'NR>1 && $8==2' bem_compression.csv" using 1:9 with linespoints title "one product, 2 threads", \
     "< awk -F, 'NR>1 && $8==1' bem_compression.csv" using 1:10 with linespoints title "12 products, 1 thread", \
     "< awk -F, 'NR>1 && $8==2' bem_compression.csv" using 1:10 with linespoints title "12 products, 2 threads", \
     "< awk -F, 'NR>1 && $8==1' bem_compression.csv" using 1:11 with linespoints lw 2 title "body step, 1 thread", \
     "< awk -F, 'NR>1 && $8==2' bem_compression.csv" using 1:11 with linespoints lw 2 title "body step, 2 threads", \
     "< awk -F, 'NR>1 && $8==2' bem_compression.csv" using 1:15 with linespoints lw 2 title "traction-free step, 2 threads"
unset multiplot
