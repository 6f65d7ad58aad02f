# Seconds by phase of the capture and dripping benchmark (bench_wet_exchange.sh): one stacked bar per scene.
set terminal pngcairo size 900,500 noenhanced
set output png
set datafile separator ','
set style data histograms
set style histogram rowstacked
set style fill solid 0.8 border -1
set boxwidth 0.6
set ylabel 'seconds over the run (2 threads)'
set title 'capture and dripping on the reference scenes: where the time goes'
set key outside right
plot csv using 5:xtic(1) skip 1 title 'transfers', '' using 6 skip 1 title 'pressure', '' using 7 skip 1 title 'hair', \
     '' using 8 skip 1 title 'capture + dripping'
