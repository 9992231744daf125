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
    // A wait for the page runs as one DevTools call, which this bounds (180 s unless
    // given): it must outlast the longest wait below.
    protocolTimeout: 1_200_000,
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
  // Drags the selected node `id`'s x axis handle 40 px along itself (pressed near its
  // tip) and waits for the one undo step; returns the move of the box's centre.
  const dragX = async (id) => {
    const centre = () => page.evaluate((id) => {
      const n = window.__assist.state.nodes.find((x) => x.id === id);
      return [0, 1, 2].map((a) => n.corners.reduce((s, p) => s + p[a], 0) / 8);
    }, id);
    const c0 = await centre();
    const steps0 = await page.evaluate(() => window.__assist.state.undo);
    const gx = (await page.evaluate(() => window.__assist.gizmo())).find((a) => a.axis === "x");
    if (!gx) fail(`no x axis handle drawn for node ${id}`);
    const len = Math.hypot(gx.tip[0] - gx.o[0], gx.tip[1] - gx.o[1]);
    const dir = [(gx.tip[0] - gx.o[0]) / len, (gx.tip[1] - gx.o[1]) / len];
    const hx = gx.o[0] + 0.85 * (gx.tip[0] - gx.o[0]), hy = gx.o[1] + 0.85 * (gx.tip[1] - gx.o[1]);
    await page.mouse.move(hx, hy);
    await page.mouse.down();
    for (let k = 1; k <= 8; k++) await page.mouse.move(hx + 5 * k * dir[0], hy + 5 * k * dir[1], { steps: 1 });
    await page.mouse.up();
    await page.waitForFunction((n) => window.__assist.state.undo > n, { timeout: 60000 }, steps0);
    const c1 = await centre();
    return [c1[0] - c0[0], c1[1] - c0[1], c1[2] - c0[2]];
  };
  return { browser, page, out, fail, shot, frames, fullFrame, dragX };
}
