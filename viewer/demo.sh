#!/usr/bin/env bash
# viewer/demo.sh — `make demo`: render the Cornell box with every built
# chapter (build/0*_*, 03c_hierarchical too) into out/demo/ (PFM + PNG + stats JSON each, small
# settings: the whole `make demo`, packages and build included, within a
# minute on 2 cores), then show them side by side: in a
# window when there is a display, else as out/demo/cornell-side-by-side.png
# (rendered headless through EGL, or OSMesa).
#
# usage: viewer/demo.sh [BUILD_DIR]     (default build; DEMO_SIZE=WxH to change the image size)
set -euo pipefail
cd "$(dirname "$0")/.."
build=${1:-build}
out=out/demo
scene=scenes/cornell.scene
size=${DEMO_SIZE:-256x256}
mkdir -p "$out"
# A converged reference (docs/reference/README.md says how it was made): with
# it every chapter's stats carry its error, and the panels show it.
reference=docs/reference/cornell-$size.pfm
ref=()
[[ -f $reference ]] && ref=(--ref "$reference")

found=0
for exe in "$build"/[0-9][0-9]*_*; do
  name=$(basename "$exe")
  [[ -f $exe && -x $exe && $name != *.* ]] || continue
  found=1
  case $name in
    01_local)     extra=(--light-samples 16 --spp 4) ;;
    02_whitted)   extra=(--spp 4) ;;
    03_radiosity) extra=(--smooth --out "$out/cornell-$name.ply") ;;
    03c_hierarchical) extra=(--smooth --eps 8e-2 --levels 5 --quadrature 1) ;;  # 2 s; at 4e-2 11 s for rel. MSE 0.0019 against 0.0022
    # The time budgets (seconds of progressive passes): the one place they are set.  With
    # the packages and the build, `make demo` on a fresh host stays within a minute.
    04_pathtrace | 06_bidirectional) extra=(--time 3) ;;
    07_metropolis) extra=(--time 2.5) ;;  # the budget counts the bootstrap (about 0.3 s at 256x256)
    *)            extra=(--time 2) ;;
  esac
  start=$(date +%s.%N)
  if "$exe" "$scene" --quiet --size "$size" --out "$out/cornell-$name.pfm" --out "$out/cornell-$name.png" \
       --stats "$out/cornell-$name.json" "${ref[@]}" "${extra[@]}" 2>"$out/cornell-$name.log"; then
    printf 'demo: %-14s %5.1f s  -> %s\n' "$name" "$(awk -v a="$start" -v b="$(date +%s.%N)" 'BEGIN { print b - a }')" "$out/cornell-$name.png"
  else
    echo "demo: $name failed (exit $?); left out of the comparison:" >&2
    cat "$out/cornell-$name.log" >&2
    rm -f "$out/cornell-$name.pfm"
  fi
done
[[ $found == 1 ]] || { echo "demo: no chapters in $build (run make first)" >&2; exit 2; }

if [[ -n ${DISPLAY:-} ]]; then
  # A window; exit status 3 means it could not open one: fall through to headless.
  status=0
  "$build/viewer" --scene cornell --dir "$out" || status=$?
  [[ $status == 3 ]] || exit "$status"
  echo "demo: no window could be opened on DISPLAY=$DISPLAY; writing a picture instead"
fi
picture=$out/cornell-side-by-side.png
"$build/viewer" --headless --size 1280x720 --scene cornell --dir "$out" --out "$picture" >/dev/null
echo "demo: side by side: $picture"
