# slides/slides.mk — the lecture decks (issue 9), included by the Makefile.
#
#   make slides        out/slides/*.html (self-contained, offline) and *.pdf (when chromium is installed)
#   make slides-html   the HTML decks only
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

.PHONY: slides slides-html
slides: deps-slides
	$(MAKE) --no-print-directory all
	$(PYTHON) slides/build.py --build $(BUILD)

slides-html: deps-slides
	$(MAKE) --no-print-directory all
	$(PYTHON) slides/build.py --build $(BUILD) --no-pdf
