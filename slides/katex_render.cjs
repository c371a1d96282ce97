// Render TeX to HTML with KaTeX at build time (no JavaScript math in the decks).
// usage: node slides/katex_render.cjs NODE_MODULES < [{tex, display}, ...] > [{html} | {error}, ...]
"use strict";
const path = require("path");
const katex = require(path.resolve(process.argv[2], "katex"));

let input = "";
process.stdin.setEncoding("utf8");
process.stdin.on("data", (chunk) => (input += chunk));
process.stdin.on("end", () => {
  const macros = {}; // shared, so \gdef in one formula is seen by the next (none used yet)
  const out = JSON.parse(input).map(({ tex, display }) => {
    try {
      return {
        html: katex.renderToString(tex, {
          displayMode: display,
          throwOnError: true,
          strict: "error",
          trust: false,
          macros,
        }),
      };
    } catch (e) {
      return { error: String(e.message || e) };
    }
  });
  process.stdout.write(JSON.stringify(out));
});
