// Open every deck in headless Chromium and report what a person would see go wrong.
// usage: node slides/check.cjs NODE_MODULES CHROMIUM DECK_DIR SCREENSHOT_DIR
// Prints one JSON object: {decks: {name: {slides, katex, katexErrors, images, brokenImages,
// consoleErrors, pageErrors, failedRequests, offlineViolations, overflowing, screenshots}}}.
"use strict";
const path = require("path");
const fs = require("fs");
const os = require("os");
const { chromium } = require(path.resolve(process.argv[2], "playwright-core"));

const [executablePath, deckDir, shotDir] = process.argv.slice(3);

async function checkDeck(browser, file) {
  const name = path.basename(file, ".html");
  const report = { consoleErrors: [], pageErrors: [], failedRequests: [], offlineViolations: [], screenshots: [] };
  const page = await browser.newPage({ viewport: { width: 1280, height: 800 } });
  page.on("console", (m) => {
    if (m.type() === "error") report.consoleErrors.push(m.text());
  });
  page.on("pageerror", (e) => report.pageErrors.push(String(e)));
  page.on("requestfailed", (r) => report.failedRequests.push(`${r.url()}: ${r.failure() && r.failure().errorText}`));
  // Offline: anything but file:// and data: is a violation, and is not even attempted.
  await page.route("**/*", (route) => {
    const url = route.request().url();
    if (url.startsWith("file:") || url.startsWith("data:")) return route.continue();
    report.offlineViolations.push(url);
    return route.abort();
  });
  await page.goto("file://" + path.resolve(file), { waitUntil: "load" });
  await page.waitForFunction(() => window.Reveal && window.Reveal.isReady(), null, { timeout: 15000 });
  await page.evaluate(() => document.fonts.ready);

  Object.assign(report, await page.evaluate(() => {
    const imgs = [...document.querySelectorAll(".slides img")];
    return {
      slides: document.querySelectorAll(".slides > section").length,
      katex: document.querySelectorAll(".katex").length,
      katexErrors: document.querySelectorAll(".katex-error").length,
      images: imgs.length,
      brokenImages: imgs.filter((i) => !(i.complete && i.naturalWidth > 0)).map((i) => i.getAttribute("src")),
    };
  }));

  // Walk the slides: find content taller or wider than the slide, note the first equation slide.
  const total = report.slides;
  report.overflowing = [];
  let equationSlide = -1;
  for (let i = 0; i < total; i++) {
    const r = await page.evaluate((k) => {
      window.Reveal.slide(k);
      const s = window.Reveal.getCurrentSlide();
      const config = window.Reveal.getConfig();
      return {
        source: s.dataset.source,
        height: s.scrollHeight,
        width: s.scrollWidth,
        maxHeight: config.height,
        maxWidth: config.width,
        equation: s.querySelector(".katex-display") !== null,
      };
    }, i);
    if (r.height > r.maxHeight + 2 || r.width > r.maxWidth + 2)
      report.overflowing.push(`${r.source}: slide ${i + 1} is ${r.width}x${r.height}, more than ${r.maxWidth}x${r.maxHeight}`);
    if (equationSlide < 0 && r.equation && i > 0) equationSlide = i;
    if (process.env.SLIDES_SHOT_ALL) {
      fs.mkdirSync(path.join(shotDir, "all"), { recursive: true });
      await page.waitForTimeout(50);
      await page.screenshot({ path: path.join(shotDir, "all", `${name}-${String(i + 1).padStart(2, "0")}.png`) });
    }
  }
  fs.mkdirSync(shotDir, { recursive: true });
  for (const [label, index] of [["title", 0], ["equation", equationSlide]]) {
    if (index < 0) continue;
    await page.evaluate((k) => window.Reveal.slide(k), index);
    await page.waitForTimeout(150);
    const shot = path.join(shotDir, `${name}-${label}.png`);
    await page.screenshot({ path: shot });
    report.screenshots.push(shot);
  }
  await page.close();
  return [name, report];
}

(async () => {
  const profile = fs.mkdtempSync(path.join(os.tmpdir(), "slides-chromium-"));
  const browser = await chromium.launch({
    executablePath,
    args: ["--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run", "--disable-background-networking",
           "--disable-component-update", "--disable-sync", "--allow-file-access-from-files"],
  });
  const decks = fs.readdirSync(deckDir).filter((f) => /^\d\d[a-z]?_\w+\.html$/.test(f)).sort();
  const result = { decks: {} };
  try {
    for (const f of decks) {
      const [name, report] = await checkDeck(browser, path.join(deckDir, f));
      result.decks[name] = report;
    }
  } finally {
    await browser.close();
    fs.rmSync(profile, { recursive: true, force: true });
  }
  process.stdout.write(JSON.stringify(result, null, 1) + "\n");
})().catch((e) => {
  process.stderr.write(String(e && e.stack || e) + "\n");
  process.exit(1);
});
