// Print decks to PDF with reveal.js's print layout (?print-pdf), in headless Chromium.
// usage: node slides/print_pdf.cjs NODE_MODULES CHROMIUM DECK.html OUT.pdf [DECK.html OUT.pdf ...]
// (chromium --print-to-pdf on the command line prints before reveal.js has laid out
// its pages and gives a blank page; here we wait for Reveal.isReady().)
"use strict";
const path = require("path");
const { chromium } = require(path.resolve(process.argv[2], "playwright-core"));

(async () => {
  const [executablePath, ...pairs] = process.argv.slice(3);
  const browser = await chromium.launch({
    executablePath,
    args: ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
           "--disable-component-update", "--disable-sync"],
  });
  try {
    for (let i = 0; i + 1 < pairs.length; i += 2) {
      const page = await browser.newPage();
      await page.route("**/*", (r) => (/^(file|data):/.test(r.request().url()) ? r.continue() : r.abort()));
      await page.goto("file://" + path.resolve(pairs[i]) + "?print-pdf", { waitUntil: "load" });
      await page.waitForFunction(() => window.Reveal && window.Reveal.isReady(), null, { timeout: 20000 });
      await page.evaluate(() => document.fonts.ready);
      await page.waitForTimeout(300);
      await page.pdf({ path: pairs[i + 1], preferCSSPageSize: true, printBackground: true });
      await page.close();
    }
  } finally {
    await browser.close();
  }
})().catch((e) => {
  process.stderr.write(String((e && e.stack) || e) + "\n");
  process.exit(1);
});
