# Bake output plots (run from out/bench/): the main thread's output seconds per frame with frames written on
# the main thread and by the writer thread, and the writer's own seconds (io_frames.csv); write time and size
# of a frame's particle arrays for each storage option (io_storage.csv).
set datafile separator ","
set terminal pngcairo size 1000,420 noenhanced

set output "io_frames.png"
set multiplot layout 1,2 title "bake output per frame (frame cache + checkpoint)"
set key outside below
set xlabel "frame"
set ylabel "seconds"
set yrange [0:*]
do for [s in "dam72k dam120k"] {
  set title s
  plot "< grep '^".s.",main thread,' io_frames.csv" using 3:4 with linespoints pt 7 title "written on the main thread", \
       "< grep '^".s.",background,' io_frames.csv" using 3:4 with linespoints pt 7 title "background: main thread", \
       "< grep '^".s.",background,' io_frames.csv" using 3:6 with linespoints pt 6 title "background: writer thread"
}
unset multiplot

set terminal pngcairo size 1100,460 noenhanced
set output "io_storage.png"
set multiplot layout 1,2 title "frame storage of 72k particles' position, velocity and affine (8.6 MB)"
set key outside below
set style fill solid 0.7
set yrange [10.6:-0.6]
unset xlabel
set ytics font ",8"
set logscale x
set xrange [0.001:1]
set title "seconds to write (through H5Fclose)"
set ylabel ""
plot "< grep '^dam72k,' io_storage.csv" using 4:0:(0.001):4:($0-0.4):($0):ytic(3) with boxxyerror title "APIC", \
     "< grep '^dam72k zero affine,' io_storage.csv" using 4:0:(0.001):4:($0):($0+0.4) with boxxyerror title "zero affine (PIC, FLIP)"
unset logscale x
set xrange [0:115]
set title "size, % of the raw bytes"
set ytics format ""
plot "< grep '^dam72k,' io_storage.csv" using (100*$8):0:(0):(100*$8):($0-0.4):($0) with boxxyerror title "APIC", \
     "< grep '^dam72k zero affine,' io_storage.csv" using (100*$8):0:(0):(100*$8):($0):($0+0.4) with boxxyerror title "zero affine (PIC, FLIP)"
unset multiplot
