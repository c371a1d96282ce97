// Markdown (markdown-it) and TeX (KaTeX) to HTML at build time, for every slide of every deck in one run.
// usage: node slides/markdown_render.cjs NODE_MODULES < JOBS > RESULTS
//   JOBS    {blocks: [markdown, ...], inline: [markdown, ...], math: [{tex, display}, ...]}
//   RESULTS {blocks: [html, ...], inline: [html, ...], math: [{html} | {error}, ...]}
// blocks are whole slides (or their speaker notes), inline are fragments such as figure captions
// (no <p> around them). slides/build.py has already replaced the project's own directives and
// every $...$ / $$...$$ by placeholders (private-use characters, which markdown-it passes through
// as text), so Markdown never sees TeX; it puts the rendered math in afterwards.
"use strict";
const path = require("path");
const modules = path.resolve(process.argv[2]);
const katex = require(path.join(modules, "katex"));
const MarkdownIt = require(path.join(modules, "markdown-it"));

// html: raw HTML in a deck (and the figures build.py made) stays as it is
const md = new MarkdownIt({ html: true, linkify: false, typographer: false });
// a literal ``` block: plain preformatted text, styled by slides.css (pre.plain)
md.renderer.rules.fence = (tokens, idx) =>
  `<pre class="plain"><code>${md.utils.escapeHtml(tokens[idx].content.replace(/\n$/, ""))}</code></pre>\n`;

let input = "";
process.stdin.setEncoding("utf8");
process.stdin.on("data", (chunk) => (input += chunk));
process.stdin.on("end", () => {
  const jobs = JSON.parse(input);
  const macros = {}; // shared, so \gdef in one formula is seen by the next (none used yet)
  const math = jobs.math.map(({ tex, display }) => {
    try {
      return {
        html: katex.renderToString(tex, { displayMode: display, throwOnError: true, strict: "error", trust: false, macros }),
      };
    } catch (e) {
      return { error: String(e.message || e) };
    }
  });
  process.stdout.write(
    JSON.stringify({
      blocks: jobs.blocks.map((text) => md.render(text)),
      inline: jobs.inline.map((text) => md.renderInline(text)),
      math,
    })
  );
});
