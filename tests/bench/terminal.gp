# bench_terminal: the drag-limited speed's error against run time, BEM and MPM balls at 4-6 cells per radius
set terminal pngcairo size 800,500 noenhanced
set output 'terminal.png'
set datafile separator ','
set key autotitle columnhead
set key top right
set logscale xy
set xlabel 'wall seconds'
set ylabel '|levelled speed / v_t(C_d 0.47) - 1|'
set title 'Drag-limited sinking at 2000 kg/m^3: error against run time (labels: cells per radius)'
plot 'terminal.csv' using (strcol(1) eq 'bem' ? $7 : 1/0):4 with linespoints title 'BEM ball', \
     '' using (strcol(1) eq 'bem' ? $7 : 1/0):4:2 with labels offset 1,1 notitle, \
     'terminal.csv' using (strcol(1) eq 'mpm' ? $7 : 1/0):4 with linespoints title 'MPM ball', \
     '' using (strcol(1) eq 'mpm' ? $7 : 1/0):4:2 with labels offset 1,1 notitle
