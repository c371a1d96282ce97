# slides/slides.mk — the lecture decks, included by the Makefile.
#
#   make slides        out/slides/*.html (self-contained, offline) and *.pdf (when chromium is installed)
#   make slides-html   the HTML decks only
#   make slides-student out/slides-student/*.html: the decks students may have while the assignment
#                      is open (slides/build.py --student: an exercise function a slide quotes shows
#                      its comment and signature only; the figures are the solution's renders)
#
# A student handout (make handout) carries slides/ as Markdown and builder, not built decks: a
# build needs node, gnuplot and the chapters, and takes minutes.  `make slides` in a handout builds
# student decks (slides/build.py sees kit/handout.json) from the handout's own code, so its figures
# are the student's renders.
#
# slides/build.py renders every figure with the chapters in $(BUILD)/ (cached in
# build/slides/cache by executable, scene and arguments), pulls the code shown
# on the slides out of chapters/ and common/ by function name (a missing
# function fails the build with deck:line), renders the Markdown with markdown-it
# and the math with KaTeX at build time (one node run, slides/markdown_render.cjs)
# and installs reveal.js, markdown-it, KaTeX and playwright-core (for the test)
# from slides/package-lock.json into build/slides/node_modules.

# npm only when no npm is on the PATH: Debian 12's nodejs (18) comes without it, but a
# NodeSource nodejs bundles its own npm and conflicts with Debian's npm package.
SLIDES_PACKAGES := nodejs $(if $(shell command -v npm 2>/dev/null),,npm) gnuplot-nox chromium fonts-dejavu-core

.PHONY: slides slides-html slides-student
slides: deps-slides
	$(MAKE) --no-print-directory all
	$(PYTHON) slides/build.py --build $(BUILD)

slides-html: deps-slides
	$(MAKE) --no-print-directory all
	$(PYTHON) slides/build.py --build $(BUILD) --no-pdf

slides-student: deps-slides
	$(MAKE) --no-print-directory all
	$(PYTHON) slides/build.py --build $(BUILD) --student --no-pdf --out out/slides-student
