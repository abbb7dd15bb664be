set terminal pngcairo size 900,600 enhanced font 'DejaVu Sans,10'
set output 'table33.png'
set title 'Table 3.3 job per level: texsyn (solid) and the seed, 2004 (dotted)'
set xlabel 'pyramid level'
set ylabel 'seconds'
set grid
set key top left box opaque
set datafile separator '\t'
set logscale y
set xtics ('4' 4, '3' 3, '2' 2, '1' 1, '0' 0)
set xrange [4.3:-0.3]
set key outside right top
plot 'gnuplot/table33.dat' index 0 using 1:2:3:4 with yerrorlines lc 1 pt 7 title 'texsyn basis', \
     'gnuplot/table33.dat' index 1 using 1:2:3:4 with yerrorlines lc 2 pt 7 title 'texsyn +parity', \
     'gnuplot/table33.dat' index 2 using 1:2:3:4 with yerrorlines lc 3 pt 7 title 'texsyn +SIMD', \
     'gnuplot/table33.dat' index 3 using 1:2:3:4 with yerrorlines lc 4 pt 7 title 'texsyn +copy map', \
     'gnuplot/table33.dat' index 4 using 1:2:3:4 with yerrorlines lc 5 pt 7 title 'texsyn +cluster', \
     'gnuplot/table33.dat' index 5 using 1:2:3:4 with yerrorlines lc 6 pt 7 title 'texsyn +LBG', \
     'gnuplot/table33.dat' index 6 using 1:2 with linespoints dt 3 lc 1 pt 6 title '2004 basis', \
     'gnuplot/table33.dat' index 7 using 1:2 with linespoints dt 3 lc 2 pt 6 title '2004 +parity', \
     'gnuplot/table33.dat' index 8 using 1:2 with linespoints dt 3 lc 3 pt 6 title '2004 +SIMD', \
     'gnuplot/table33.dat' index 9 using 1:2 with linespoints dt 3 lc 4 pt 6 title '2004 +copy map', \
     'gnuplot/table33.dat' index 10 using 1:2 with linespoints dt 3 lc 5 pt 6 title '2004 +cluster', \
     'gnuplot/table33.dat' index 11 using 1:2 with points dt 3 lc 6 pt 6 title '2004 +LBG'
