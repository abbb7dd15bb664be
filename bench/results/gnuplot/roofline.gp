set terminal pngcairo size 900,600 enhanced font 'DejaVu Sans,10'
set output 'roofline.png'
set title 'L1 scan kernels (W_N=7, 1 thread) against the measured memory bandwidth'
set xlabel 'arithmetic intensity: operations per byte of reference read (3 x queries per batch)'
set ylabel 'G operations / s'
set grid
set key top left box opaque
set datafile separator '\t'
set logscale x
set logscale y
set xtics ('3' 3, '96' 96, '384' 384)
set xrange [0.8:768]
set key outside right top
plot 'gnuplot/roofline.dat' index 0 using 1:2 with lines lw 2 dt 1 lc rgb 'black' title 'DRAM roof, 1t (13.1 GB/s)', \
     'gnuplot/roofline.dat' index 1 using 1:2 with lines lw 2 dt 2 lc rgb 'black' title 'DRAM roof, 2t (13.3 GB/s)', \
     'gnuplot/roofline.dat' index 2 using 1:2 with linespoints lc 1 pt 7 ps 1.3 dt 1 title 'scalar, set in L2', \
     'gnuplot/roofline.dat' index 3 using 1:2 with linespoints lc 1 pt 6 ps 1.3 dt 3 title 'scalar, set in DRAM', \
     'gnuplot/roofline.dat' index 4 using 1:2 with linespoints lc 2 pt 7 ps 1.3 dt 1 title 'mmx, set in L2', \
     'gnuplot/roofline.dat' index 5 using 1:2 with linespoints lc 2 pt 6 ps 1.3 dt 3 title 'mmx, set in DRAM', \
     'gnuplot/roofline.dat' index 6 using 1:2 with linespoints lc 3 pt 7 ps 1.3 dt 1 title 'sse2, set in L2', \
     'gnuplot/roofline.dat' index 7 using 1:2 with linespoints lc 3 pt 6 ps 1.3 dt 3 title 'sse2, set in DRAM', \
     'gnuplot/roofline.dat' index 8 using 1:2 with linespoints lc 4 pt 7 ps 1.3 dt 1 title 'avx2, set in L2', \
     'gnuplot/roofline.dat' index 9 using 1:2 with linespoints lc 4 pt 6 ps 1.3 dt 3 title 'avx2, set in DRAM', \
     'gnuplot/roofline.dat' index 10 using 1:2 with linespoints lc 5 pt 7 ps 1.3 dt 1 title 'avx512, set in L2', \
     'gnuplot/roofline.dat' index 11 using 1:2 with linespoints lc 5 pt 6 ps 1.3 dt 3 title 'avx512, set in DRAM'
