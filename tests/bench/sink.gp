# Two-way BEM ball sinking in a deep tank (run from out/bench/; tests/bench/bench_sink.sh writes sink.csv): its sinking
# speed against time at 1200 and 2000 kg/m³.
set datafile separator ","
set terminal pngcairo size 900,560 noenhanced
set output "sink.png"
set grid
set key top left font ",9"
set xlabel "time (s)"
set ylabel "sinking speed (m/s)"
set title "a 0.1 m ball sinking through still water (two-way, dx 0.02 m)"
plot "< grep '^1200,' sink.csv" using 3:5 with linespoints pt 5 title "1200 kg/m3", \
     "< grep '^2000,' sink.csv" using 3:5 with linespoints pt 7 title "2000 kg/m3"
