#!/usr/bin/env node
// Renders a .glb with the HHD_lightmap runtime in headless Chromium to a PNG (make demo:
// out/demo/demo.glb -> out/demo/preview_web.png), from the file's first camera (the Blender
// scene camera when the export carried it; else a view framing the scene).
//   node web/test/render.mjs IN.glb OUT.png [--width 960] [--height H] [--mode shaded|lightmap]
//        [--tone agx|neutral|none] [--exposure 1]
//   node web/test/render.mjs --check     exit 0 when a Chromium is found and starts
import { HOW_TO_GET_CHROMIUM, findChromium, openSession } from './browser.mjs';

const args = process.argv.slice(2);
const opt = (name, fallback) => {
  const i = args.indexOf(`--${name}`);
  return i >= 0 ? args[i + 1] : fallback;
};

if (!findChromium()) {
  console.error(HOW_TO_GET_CHROMIUM);
  process.exit(2);
}
const session = await openSession();
try {
  if (args.includes('--check')) {
    console.log(`${session.version}: ${session.info.renderer}`);
  } else {
    const [input, output] = args.filter((a, i) => !a.startsWith('--') && !(i > 0 && args[i - 1].startsWith('--')));
    if (!input || !output) throw new Error('usage: render.mjs IN.glb OUT.png [--width W] [--height H] [--mode shaded|lightmap]');
    const summary = await session.call('load', { url: session.server.mount(input), plugin: true });
    const width = Number(opt('width', 960));
    const aspect = summary.camera && summary.camera.aspect ? summary.camera.aspect : 16 / 9;
    const height = Number(opt('height', Math.round(width / aspect)));
    await session.page.setViewportSize({ width: Math.max(width, 64), height: Math.max(height, 64) });
    await session.call('show', {
      width,
      height,
      mode: opt('mode', 'shaded'),
      toneMapping: opt('tone', 'agx'),
      exposure: Number(opt('exposure', 1)),
    });
    await session.page.locator('canvas#view').screenshot({ path: output });
    const errors = session.errors.filter((e) => !e.includes('favicon'));
    console.log(
      `${output}: ${width}x${height}, ${summary.receivers} receivers, ${summary.lightSets.length} light sets, ` +
        `${summary.cameras ? 'the exported camera' : 'no camera in the file: a view framing the scene'}` +
        (errors.length ? `\n${errors.join('\n')}` : ''),
    );
  }
} finally {
  await session.close();
}
process.exit(0);
