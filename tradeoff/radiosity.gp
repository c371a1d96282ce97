# radiosity.gp — radiosity error against iteration count, one line per
# (solver, patch size): at a fixed patch size the error stops falling once the
# iteration has converged (the discretisation floor); finer patches lower the floor.
# Called by tradeoff.py with -e: term, out, title, files (K rmse time_s S patches),
#   names (quoted titles), colors (colour index per file = patch size), dashes
#   (dash type per file = solver), refrmse.
if (term eq 'png') { set terminal pngcairo size 1100,760 font 'DejaVu Sans,10' noenhanced } \
else { set terminal svg size 1100,760 font 'DejaVu Sans,10' noenhanced dynamic }
set output out
set title title
set logscale xy
set format x '%g'
set format y '%g'
set xlabel 'iterations K (--tol 0; shooting: K x patches shots)'
set ylabel 'RMSE against the reference'
set grid xtics ytics mxtics mytics lc rgb '#dddddd'
# The legend below the plot, so the plot keeps the full width.
set key outside below center horizontal maxcols 2 Left reverse samplen 2 box
set xlabel offset 0,-0.3
array palette[8] = ['#1f77b4', '#ff7f0e', '#2ca02c', '#d62728', '#9467bd', '#8c564b', '#e377c2', '#17becf']
plot for [i=1:words(files)] word(files, i) using 1:2 with linespoints \
         lc rgb palette[int(word(colors, i))] dt int(word(dashes, i)) lw 2 pt int(word(dashes, i)) + 5 ps 0.9 \
         title word(names, i), \
     refrmse with lines lc rgb '#444444' lw 1 dt 4 title "reference's own RMSE (estimate)"
