set terminal pngcairo size 800,500 enhanced font 'DejaVu Sans,10'
set output 'scaling-aerial.png'
set title 'Speed-up over 1 worker (2 cores; bars: min-max)'
set xlabel 'workers (texsyn-worker --threads 1)'
set ylabel 'speed-up T(1)/T(N)'
set grid
set key top left box opaque
set datafile separator '\t'
set logscale x
set logscale y
set arrow from 2, graph 0 to 2, graph 1 nohead dt 2 lc rgb 'gray40'
set label '2 cores' at 2, graph 0.95 offset 0.5,0 textcolor rgb 'gray30'
set xtics ('1' 1, '2' 2)
set xrange [0.9:2.2]
set yrange [0.25:2.2]
set key bottom left
plot 'gnuplot/scaling-aerial.dat' index 0 using 1:2 with lines dt 3 lc rgb 'gray' title 'ideal (speed-up = N)', \
     'gnuplot/scaling-aerial.dat' index 1 using 1:2 with lines dt 2 lc rgb 'black' title 'bound of 2 cores', \
     'gnuplot/scaling-aerial.dat' index 2 using 1:2:3:4 with yerrorlines  title 'aerial'
