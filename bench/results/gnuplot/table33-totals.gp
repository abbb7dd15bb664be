set terminal pngcairo size 800,500 enhanced font 'DejaVu Sans,10'
set output 'table33-totals.png'
set title 'Table 3.3 job, total seconds per column (seed''s +LBG: level 0 only)'
set xlabel ''
set ylabel 'seconds'
set grid
set key top left box opaque
set datafile separator '\t'
set logscale y
set style data histogram
set style histogram errorbars gap 1 lw 1
set style fill solid 0.7 border -1
set boxwidth 0.9
set xtics nomirror
set key top left
set yrange [*:*]
plot 'gnuplot/table33-totals.dat' using 2:3:4:xtic(1) title 'texsyn', \
     'gnuplot/table33-totals.dat' using 5:6:7:xtic(1) title '2004 (seed)'
