# errortime.gp — error against time on log-log axes, one curve per method.
# Called by tradeoff.py with -e: term ('png'|'svg'), out, title,
#   files  (one data file per curve: time_s rmse relmse ssim [cpu_s])
#   names  (their titles, quoted words), styles (line style per curve, see below)
#   t0, e0 (a point the N^-1/2 guide passes through), refrmse (the reference's own RMSE)
#   tmin, tmax, emin, emax (axis ranges)
#   optional: xcol (the data file's column of the x axis, default 1), xlabel (its label),
#   note (a sentence printed under the title: why a method loses on this scene)
if (!exists("xcol")) xcol = 1
if (!exists("xlabel")) xlabel = 'time (s): prepare_s + render_s, median of repeats'
if (term eq 'png') { set terminal pngcairo size 1000,900 font 'DejaVu Sans,11' noenhanced } \
else { set terminal svg size 1000,900 font 'DejaVu Sans,11' noenhanced dynamic }
set output out
set title title
# The note: wrapped at about 110 characters a line, under the title.
if (exists("note")) { \
  wrapped = ''; line = ''; \
  do for [i=1:words(note)] { w = word(note, i); \
    if (strlen(line) + strlen(w) > 110) { wrapped = wrapped . line . "\n"; line = w } \
    else { line = (strlen(line) > 0) ? line . ' ' . w : w } }; \
  wrapped = wrapped . line; \
  set title title . "\n" . wrapped font ',10' }
set logscale xy
set xrange [tmin:tmax]
set yrange [emin:emax]
set format x '10^{%L}'
set format y '10^{%L}'
set format x '%g'
set format y '%g'
set xlabel xlabel
set ylabel 'RMSE against the reference'
set grid xtics ytics mxtics mytics lc rgb '#dddddd'
# The legend below the plot, in columns, so the plot keeps the full width.
set key outside below center horizontal maxcols 2 Left reverse samplen 2 box
set xlabel offset 0,-0.3

# 1-4 path tracing estimators, 5-8 radiosity solvers, 9-10 Whitted, 11 local, 12 photon mapping,
# 13-15 chapter 6: light tracing, BDPT, VCM; 16-17 chapter 7: PSSMLT, MMLT (dot-dashed)
set style line 1  lc rgb '#9467bd' lw 2 pt 7  ps 0.9
set style line 2  lc rgb '#1f77b4' lw 2 pt 5  ps 0.9
set style line 3  lc rgb '#17becf' lw 2 pt 9  ps 1.0
set style line 4  lc rgb '#d62728' lw 2.5 pt 13 ps 1.1
set style line 5  lc rgb '#2ca02c' lw 2 pt 4  ps 1.0 dt 1
set style line 6  lc rgb '#8c564b' lw 2 pt 6  ps 1.0 dt 1
set style line 7  lc rgb '#bcbd22' lw 2 pt 8  ps 1.0 dt 1
set style line 8  lc rgb '#ff7f0e' lw 2 pt 12 ps 1.0 dt 1
set style line 9  lc rgb '#7f7f7f' lw 2 pt 2  ps 1.0 dt 3
set style line 10 lc rgb '#000000' lw 1.5 pt 3 ps 1.0 dt 3
set style line 11 lc rgb '#e377c2' lw 2 pt 1  ps 1.2 dt 2
set style line 12 lc rgb '#ff7f0e' lw 2.5 pt 11 ps 1.2 dt 1
set style line 13 lc rgb '#8fbc8f' lw 2 pt 10 ps 1.1 dt 2
set style line 14 lc rgb '#1f3fbf' lw 2.5 pt 5 ps 1.0 dt 1
set style line 15 lc rgb '#2ca02c' lw 3 pt 7 ps 1.1 dt 1
set style line 16 lc rgb '#e377c2' lw 2 pt 12 ps 1.2 dt 4
set style line 17 lc rgb '#8b0000' lw 2.5 pt 6 ps 1.2 dt 4

guide(t) = e0 * sqrt(t0 / t)
plot for [i=1:words(files)] word(files, i) using int(xcol):2 with linespoints ls int(word(styles, i)) title word(names, i), \
     guide(x) with lines lc rgb '#888888' lw 1.5 dt 2 title 'N^-1/2 guide (RMSE ~ time^-1/2)', \
     refrmse with lines lc rgb '#444444' lw 1 dt 4 title "reference's own RMSE (estimate)"
