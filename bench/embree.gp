# embree.gp — ray-casting throughput against triangle count, ours and Embree's,
# 1 thread (bench/bench_00b_embree.py).  Called with -e: out (PNG), procedural
# and scan (CSV: triangles, then ours and Embree's million rays per second for
# the camera, bounce and shadow sets; scan may be ''): ours filled, Embree's
# open symbols; the scans' symbols are triangles.
set terminal pngcairo size 1000,640 font 'DejaVu Sans,10' noenhanced
set output out
set title 'Rays per second against triangles, 1 thread: ours (solid) and Embree 3 (dashed); tori as lines, scans as points'
set logscale x
set xlabel 'triangles'
set ylabel 'million rays per second'
set yrange [0:*]
set xrange [700:1.5e6]
set grid xtics ytics mxtics lc rgb '#dddddd'
set key outside below center horizontal maxcols 3 Left reverse samplen 3 box
set format x '%.0e'
array colour[3] = ['#1f77b4', '#d62728', '#2ca02c']
array name[3] = ['camera', 'bounce (closest hit)', 'shadow']
plot for [s=1:3] procedural using 1:(column(2 * s)) with linespoints lc rgb colour[s] lw 2 pt 7 dt 1 \
         title 'ours, '.name[s], \
     for [s=1:3] procedural using 1:(column(2 * s + 1)) with linespoints lc rgb colour[s] lw 2 pt 6 dt 2 \
         title 'Embree, '.name[s], \
     for [s=1:(scan eq '' ? 0 : 3)] scan using 1:(column(2 * s)) with points lc rgb colour[s] pt 9 ps 1.6 notitle, \
     for [s=1:(scan eq '' ? 0 : 3)] scan using 1:(column(2 * s + 1)) with points lc rgb colour[s] pt 8 ps 1.6 notitle
