# Transfer benchmark plot (run from out/bench/): million particle-steps (one P2G + one G2P) per second per
# core for each kernel and particle order, with 1 and 2 threads (transfer.csv).
set datafile separator ","
set terminal pngcairo size 900,480 noenhanced
set output "transfer.png"
set title "collocated-grid APIC transfers, 3-D, 1M particles: M particle-steps/s per core"
set style data histograms
set style histogram clustered gap 1
set style fill solid 0.8 border -1
set boxwidth 0.9
set key top right
set ylabel "M particle-steps / s / core"
set yrange [0:*]
set grid ytics
plot "transfer.csv" using 6:xticlabels(1) skip 1 title "1 thread", \
     "" using 10 skip 1 title "2 threads"
