# hierarchical.gp — called by hierarchical.py with -e: term, out, kind (error|links),
#   uniform, hierarchical (data files: time_s rmse elements links), slope (links against elements).
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
    set title sprintf('hierarchical radiosity: links against elements (fitted slope %.2f)', slope)
    set xlabel 'elements (all levels of the quadtrees)'
    set ylabel 'links'
    plot hierarchical using 3:4 with linespoints lw 2 pt 5 title 'links (one per --eps)', \
         uniform using 3:($3 * $3) with linespoints lw 2 pt 7 title 'uniform: patches^2 form factors'
}
