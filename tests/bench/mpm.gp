# Run time against error on the rotating disk (input mpm.csv from bench_mpm): angular-momentum and energy
# error after 1 s against seconds, one series per scheme and integrator (points: 16², 32², 64² cells at
# three step sizes each).
set datafile separator ","
set terminal pngcairo size 1200,480 noenhanced
set output "mpm.png"
set multiplot layout 1,2 title "rotating disk (APIC paper 6.1): error after 0.5 s against run time"
set key top right font ",8"
set logscale xy
set format y "%.0e"
set xlabel "seconds"
set ylabel "|L(0.5 s)/L(0) - 1|"
series = "APIC,symplectic_euler APIC,midpoint APIC,backward_euler PIC,symplectic_euler PIC,midpoint PIC,backward_euler FLIP,symplectic_euler FLIP,midpoint FLIP,backward_euler"
plot for [s in series] "< grep ,".s.", mpm.csv" using 8:(($11) > 1e-17 ? $11 : 1e-17) with points title s
set ylabel "|E(0.5 s)/E(0) - 1|"
plot for [s in series] "< grep ,".s.", mpm.csv" using 8:(($12) > 1e-17 ? $12 : 1e-17) with points title s
unset multiplot
