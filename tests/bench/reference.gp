# Reference-scene benchmark plot (run from out/bench/): wall seconds per simulated 5 ms of each bake of
# box_test and dragging_test (reference.csv), every repetition, against the reference code's own step.
set datafile separator ","
set terminal pngcairo size 1000,420 noenhanced
set output "reference.png"
set title "box_test and dragging_test: wall seconds per simulated 5 ms (frame writes included), 2 threads"
set ylabel "seconds per simulated 5 ms"
set xtics ("quiet" 0, "busy neighbour" 1, "active, busy" 2, "active, quiet" 3)
set xrange [-0.5:3.5]
set yrange [0:*]
set key outside right
cond(c) = c eq "quiet" ? 0 : (c eq "busy" ? 1 : (c eq "busy_active" ? 2 : 3))
plot "reference.csv" using (strcol(1) eq "box_test" ? cond(strcol(2)) - 0.1 : 1/0):5 skip 1 with points pt 7 ps 1.5 title "box_test", \
     "" using (strcol(1) eq "dragging_test" ? cond(strcol(2)) + 0.1 : 1/0):5 skip 1 with points pt 5 ps 1.5 title "dragging_test", \
     0.262 with lines dt 2 lw 2 title "reference code, box_test (0.262 s)", \
     0.52 with lines dt 3 lw 2 title "reference code, dragging_test (0.52 s)", \
     0.3 * 0.262 with lines lw 1 title "goal for box_test (0.3x)", \
     0.3 * 0.52 with lines lw 1 title "goal for dragging_test (0.3x)"
