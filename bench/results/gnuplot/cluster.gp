set terminal pngcairo size 900,500 enhanced font 'DejaVu Sans,10'
set output 'cluster.png'
set title 'Table 3.3 job: embedded and on loopback clusters (bars: min-max)'
set xlabel ''
set ylabel 'wall seconds'
set grid
set key top left box opaque
set datafile separator '\t'
set style data histogram
set style histogram errorbars gap 1 lw 1
set style fill solid 0.7 border -1
set boxwidth 0.9
set xtics nomirror
set key top left
set yrange [0:*]
set xtics font ',8'
plot 'gnuplot/cluster.dat' using 2:3:4:xtic(1) title 'parity'
