# hierarchical.gp — called by hierarchical.py with -e: term, out, kind (error|links),
#   uniform, hierarchical, fixed (data files: time_s rmse elements links), slope (fixed --eps), sweep_slope.
if (term eq 'png') { set terminal pngcairo size 900,620 font 'DejaVu Sans,10' noenhanced } \
else { set terminal svg size 900,620 font 'DejaVu Sans,10' noenhanced dynamic }
set output out
set logscale xy
set format x '%g'
set format y '%g'
set grid xtics ytics mxtics mytics lc rgb '#dddddd'
set key top right box
if (kind eq 'error') {
    set title 'Cornell box: radiosity error against time, uniform patches and hierarchical'
    set xlabel 'time (s): form factors or links, solve, pixels'
    set ylabel 'RMSE against the path-traced reference'
    plot uniform using 1:2 with linespoints lw 2 pt 7 title 'uniform (Jacobi), patch size 200 .. 25 mm', \
         hierarchical using 1:2 with linespoints lw 2 pt 5 title 'hierarchical, --eps 0.1 .. 0.005'
} else {
    set title sprintf('hierarchical radiosity: links against elements (slope %.2f at fixed --eps, %.2f along the --eps sweep)', slope, sweep_slope)
    set xlabel 'elements (all levels of the quadtrees)'
    set ylabel 'links'
    plot fixed using 3:4 with linespoints lw 2 pt 9 title '--eps 0.02, growing --levels', \
         hierarchical using 3:4 with linespoints lw 2 pt 5 title 'falling --eps (--levels 8)', \
         uniform using 3:($3 * $3) with linespoints lw 2 pt 7 title 'uniform: patches^2 form factors'
}
