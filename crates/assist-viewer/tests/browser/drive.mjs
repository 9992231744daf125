// Drives the viewer page in headless chromium as a user would: it loads and shows a frame;
// a click selects an object (its row is highlighted, its pixels change); `-` deletes it
// (its colour leaves the panoptic frame); Ctrl+Z brings it back; `t` + drag moves it (its
// mask's centroid moves the way the pointer did); a typed instruction applies; save-as
// writes a scene; hiding an object takes it out of the view and showing brings it back; a
// row's rename changes its label; dragging the x axis handle moves the object along x; the camera list shows the views' photographs and jumps. Prints one JSON object of measurements; exits 1 on the first failure.
// Usage: node drive.mjs URL SHOTS_DIR CHROMIUM
import { start } from "./harness.mjs";

const [url, shots, chromium] = process.argv.slice(2);
const { browser, page, out, fail, shot, frames, fullFrame, dragX } = await start(shots, chromium, "");
try {
  page.on("dialog", (d) => d.accept(d.message().startsWith("Rename") ? "renamed object" : "browser-saved.assist"));
  await page.goto(url);
  // Pixels of the frame image, as the page shows it, with the mask of `color`.
  const analyse = (color) => page.evaluate((color) => {
    const img = document.getElementById("frame");
    const c = document.createElement("canvas");
    c.width = img.naturalWidth; c.height = img.naturalHeight;
    const g = c.getContext("2d");
    g.drawImage(img, 0, 0);
    const d = g.getImageData(0, 0, c.width, c.height).data;
    let n = 0, sx = 0, sy = 0, sum = 0;
    for (let y = 0; y < c.height; y++) for (let x = 0; x < c.width; x++) {
      const k = 4 * (y * c.width + x);
      sum += d[k] + d[k + 1] + d[k + 2];
      if (color && Math.abs(d[k] - color[0]) + Math.abs(d[k + 1] - color[1]) + Math.abs(d[k + 2] - color[2]) < 60) {
        n += 1; sx += x; sy += y;
      }
    }
    const r = img.getBoundingClientRect();
    return { width: c.width, height: c.height, count: n,
      centroid: n ? [r.left + (sx / n + 0.5) * r.width / c.width, r.top + (sy / n + 0.5) * r.height / c.height] : null,
      mean: sum / (3 * c.width * c.height), data: Array.from(d) };
  }, color);
  const setOutput = async (o) => {
    const n = await frames();
    await page.select("#output", o);
    await fullFrame(n);
  };

  // 1. The page loads and shows a frame.
  await fullFrame(0);
  const first = await analyse(null);
  if (!(first.width > 0 && first.mean > 5)) fail(`no visible frame: ${JSON.stringify({ w: first.width, mean: first.mean })}`);
  await shot("loaded");
  // 1b. The camera list shows each view's photograph; clicking one jumps there (and back).
  await page.waitForFunction(() => Array.from(document.querySelectorAll("#cameras .cam img")).every((i) => i.complete), { timeout: 60000 });
  const thumbs = await page.$$eval("#cameras .cam img", (ims) => ims.map((i) => i.naturalWidth));
  out.thumbnails = thumbs.length;
  if (thumbs.length < 2 || thumbs.some((w) => w !== 96)) fail(`camera thumbnails: ${JSON.stringify(thumbs)}`);
  let n0 = await frames();
  await page.click('#cameras .cam[data-index="1"]');
  await fullFrame(n0);
  const elsewhere = await analyse(null);
  let jumped = 0;
  for (let k = 0; k < elsewhere.data.length; k += 4) jumped += Math.abs(elsewhere.data[k] - first.data[k]);
  out.camera_jump_mean_change = jumped / (elsewhere.data.length / 4);
  if (out.camera_jump_mean_change < 2) fail("jumping to another camera did not change the view");
  await shot("camera");
  n0 = await frames();
  await page.click('#cameras .cam[data-index="0"]');
  await fullFrame(n0);
  const state0 = await page.evaluate(() => window.__assist.state);
  const objects = state0.nodes.filter((n) => !n.background);
  // The object to work on: the one covering most panoptic pixels.
  await setOutput("panoptic");
  let best = null;
  for (const o of objects) {
    const a = await analyse(o.color);
    if (!best || a.count > best.a.count) best = { o, a };
  }
  if (!best || best.a.count < 20) fail("no object visible in the panoptic frame");
  const target = best.o;
  out.target = { id: target.id, label: target.label, pixels: best.a.count };
  await shot("panoptic");
  await setOutput("rgb");
  const before = await analyse(null);

  // 2. A click on its pixels selects it: its row is highlighted and its pixels change.
  let n = await frames();
  await page.mouse.click(best.a.centroid[0], best.a.centroid[1]);
  await page.waitForFunction((id) => window.__assist.state.selected === id, { timeout: 60000 }, target.id);
  await fullFrame(n);
  const row = await page.$eval(`.node[data-id="${target.id}"]`, (e) => e.classList.contains("selected"));
  if (!row) fail("the selected row is not highlighted");
  const after = await analyse(null);
  let changed = 0;
  for (let k = 0; k < after.data.length; k += 4) {
    if (Math.abs(after.data[k] - before.data[k]) + Math.abs(after.data[k + 1] - before.data[k + 1]) + Math.abs(after.data[k + 2] - before.data[k + 2]) > 60) changed += 1;
  }
  out.highlighted_pixels = changed;
  if (changed < 0.3 * best.a.count) fail(`the selection changed only ${changed} pixels`);
  await shot("selected");

  // 3. `-` deletes it: gone from the state and from the panoptic frame.
  await setOutput("panoptic");
  n = await frames();
  await page.keyboard.press("-");
  await page.waitForFunction((id) => !window.__assist.state.nodes.some((x) => x.id === id), { timeout: 60000 }, target.id);
  await fullFrame(n);
  const gone = await analyse(target.color);
  out.pixels_after_delete = gone.count;
  if (gone.count > 0.05 * best.a.count) fail(`after delete ${gone.count} pixels still have its colour`);
  await shot("deleted");

  // 4. Ctrl+Z brings it back.
  n = await frames();
  await page.keyboard.down("Control"); await page.keyboard.press("z"); await page.keyboard.up("Control");
  await page.waitForFunction((id) => window.__assist.state.nodes.some((x) => x.id === id), { timeout: 60000 }, target.id);
  await fullFrame(n);
  const back = await analyse(target.color);
  out.pixels_after_undo = back.count;
  if (back.count < 0.8 * best.a.count) fail(`after undo only ${back.count} of ${best.a.count} pixels are back`);
  await shot("undone");

  // 4b. "hide" in its row: its colour leaves this view's panoptic frame (the scene keeps
  // it); "show" brings it back.
  n = await frames();
  await page.click(`.node[data-id="${target.id}"] .eye`);
  await page.waitForFunction((id) => (window.__assist.state.hidden || []).includes(id), { timeout: 60000 }, target.id);
  await fullFrame(n);
  const hiddenPx = await analyse(target.color);
  out.pixels_when_hidden = hiddenPx.count;
  if (hiddenPx.count > 0.05 * best.a.count) fail(`hidden, ${hiddenPx.count} pixels still have its colour`);
  if (!(await page.$eval(`.node[data-id="${target.id}"]`, (e) => e.classList.contains("hidden")))) fail("the hidden row is not marked");
  await shot("hidden");
  n = await frames();
  await page.click(`.node[data-id="${target.id}"] .eye`);
  await page.waitForFunction((id) => !(window.__assist.state.hidden || []).includes(id), { timeout: 60000 }, target.id);
  await fullFrame(n);
  const shown = await analyse(target.color);
  if (shown.count < 0.8 * best.a.count) fail(`shown again, only ${shown.count} pixels are back`);

  // 5. Select it again, `t` + drag right: its mask's centroid moves right.
  n = await frames();
  await page.mouse.click(back.centroid[0], back.centroid[1]);
  await page.waitForFunction((id) => window.__assist.state.selected === id, { timeout: 60000 }, target.id);
  await fullFrame(n);
  await page.keyboard.press("t");
  const [x0, y0] = back.centroid;
  await page.mouse.move(x0, y0);
  await page.mouse.down();
  for (let k = 1; k <= 8; k++) await page.mouse.move(x0 + 10 * k, y0, { steps: 1 });
  await page.mouse.up();
  await page.keyboard.press("Enter");
  await page.waitForFunction(() => window.__assist.state.log.some((l) => l.startsWith("moved")), { timeout: 60000 });
  // The frame rendered after the committed state (drag previews may still be arriving).
  await page.waitForFunction(() => window.__assist.frame && window.__assist.frame.seq > window.__assist.stateSeq && !window.__assist.frame.preview, { timeout: 120000 });
  await new Promise((r) => setTimeout(r, 100));
  const moved = await analyse(target.color);
  out.centroid_before = back.centroid; out.centroid_after = moved.centroid;
  if (!moved.centroid || moved.centroid[0] - back.centroid[0] < 20) fail(`the drag moved the mask by ${moved.centroid && moved.centroid[0] - back.centroid[0]} px, expected about 80 to the right`);
  await shot("dragged");

  // 5b. The axis handle: press on the x axis near its tip and drag 40 px along it; the
  // object moves along +x alone, as one step.
  out.handle_moved = await dragX(target.id);
  const m = out.handle_moved;
  if (!(m[0] > 0.005) || Math.abs(m[1]) > 1e-6 || Math.abs(m[2]) > 1e-6) fail(`the x handle moved the object by ${JSON.stringify(m)}`);
  await shot("handle");

  // 6. A typed instruction applies.
  await setOutput("rgb");
  await page.click("#text");
  await page.keyboard.type(`move the ${target.label} 3 cm up`);
  await page.keyboard.press("Enter");
  await page.waitForFunction(() => window.__assist.resolved && window.__assist.resolved.applied, { timeout: 60000 });
  out.resolved = await page.evaluate(() => window.__assist.resolved.actions);
  await shot("instruction");

  // 6b. "rename" in its row (the prompt answers "renamed object"): the label changes.
  await page.click(`.node[data-id="${target.id}"] .ren`);
  await page.waitForFunction((id) => window.__assist.state.nodes.some((x) => x.id === id && x.label === "renamed object"), { timeout: 60000 }, target.id);
  const rowText = await page.$eval(`.node[data-id="${target.id}"] .label`, (e) => e.textContent);
  if (rowText !== "renamed object") fail(`the row says ${rowText}`);
  await shot("renamed");

  // 7. Save as (the prompt answers browser-saved.assist).
  await page.click("#saveas");
  await page.waitForFunction(() => window.__assist.saved, { timeout: 60000 });
  out.saved = await page.evaluate(() => window.__assist.saved);
  await shot("saved");
  out.ok = true;
  console.log(JSON.stringify(out));
} catch (e) {
  fail(String(e && e.stack || e));
} finally {
  await browser.close();
}
