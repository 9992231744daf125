// What the browser scripts share: headless chromium (never downloaded: Debian's), a
// 960×480 page, screenshots numbered per step, waits for a full (not preview) frame, and
// one JSON report on stdout (`fail` prints it with the error and exits 1).
import puppeteer from "puppeteer-core";
import { mkdirSync } from "node:fs";

export async function start(shots, chromium, prefix = "") {
  mkdirSync(shots, { recursive: true });
  const out = { steps: [] };
  const browser = await puppeteer.launch({
    executablePath: chromium,
    headless: true,
    args: ["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"],
  });
  const page = await browser.newPage();
  await page.setViewport({ width: 960, height: 480 });
  let step = 0;
  const fail = (msg) => {
    out.error = msg;
    console.log(JSON.stringify(out));
    process.exit(1);
  };
  const shot = async (name) => {
    step += 1;
    await page.screenshot({ path: `${shots}/${prefix}${String(step).padStart(2, "0")}-${name}.png` });
    out.steps.push(name);
  };
  const frames = () => page.evaluate(() => window.__assist.frames);
  // Waits for a full frame newer than `after` (a frame count).
  const fullFrame = async (after) => {
    await page.waitForFunction(
      (n) => window.__assist.frames > n && window.__assist.frame && !window.__assist.frame.preview,
      { timeout: 120000 }, after);
    await new Promise((r) => setTimeout(r, 100));
  };
  return { browser, page, out, fail, shot, frames, fullFrame };
}
