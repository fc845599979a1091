#!/usr/bin/env node
// The browser test harness: one Chromium for many requests (tests/test_web_runtime.py keeps one
// per test module). Reads one JSON request per line on stdin, answers one JSON line on stdout
// (logs go to stderr):
//   {"cmd": "load", "file": "/abs/scene.glb", "plugin": true, "options": {...}}
//        -> {"ok": true, "result": {summary of the loaded scene}}
//   {"cmd": "render", "mode": "lightmap" | "uv" | "nv" | "n" | "albedo" | "hhd" | "dir" | "shaded" | "stock",
//    "width": W, "height": H, "weights": {"<set>": [r, g, b]}, "out": "/abs/file.f32"}
//        -> writes H*W*4 float32 (rows top first, RGBA) to `out`; {"ok": true, "result": {...}}
//   {"cmd": "blend", "inputs": "/abs/in.f32", "sets": K, "texels": N, "weights": [[r,g,b] x K], "out": "/abs/out.f32"}
//        -> the plugin's GLSL light-set blend over N synthetic texels (see page.js `blend`)
//   {"cmd": "screenshot", "width": W, "height": H, "out": "/abs/file.png"}  (tone-mapped sRGB view)
//   {"cmd": "errors"} -> the page's console errors and warnings since the last call
//   {"cmd": "quit"}
// `node harness.mjs --check` prints the browser and WebGL it found and exits.
import fs from 'node:fs';
import readline from 'node:readline';

import { HOW_TO_GET_CHROMIUM, findChromium, openSession } from './browser.mjs';

const log = (...a) => process.stderr.write(a.join(' ') + '\n');

const chromiumPath = findChromium();
if (!chromiumPath) {
  process.stdout.write(JSON.stringify({ ok: false, nochromium: true, error: HOW_TO_GET_CHROMIUM }) + '\n');
  process.exit(3);
}

let session;
try {
  session = await openSession({ chromiumPath, log: process.env.HHD_WEB_VERBOSE ? log : () => {} });
} catch (e) {
  process.stdout.write(JSON.stringify({ ok: false, error: `could not start ${chromiumPath}: ${e.message}` }) + '\n');
  process.exit(4);
}
const hello = { ok: true, ready: true, chromium: chromiumPath, version: session.version, webgl: session.info };
if (process.argv.includes('--check')) {
  console.log(JSON.stringify(hello));
  await session.close();
  process.exit(0);
}
process.stdout.write(JSON.stringify(hello) + '\n');

async function handle(req) {
  switch (req.cmd) {
    case 'load': {
      const url = req.url || session.server.mount(req.file);
      return session.call('load', { url, plugin: req.plugin !== false, options: req.options || {} });
    }
    case 'render': {
      const r = await session.call('render', req);
      if (req.out) fs.writeFileSync(req.out, Buffer.from(r.data, 'base64'));
      delete r.data;
      return r;
    }
    case 'blend': {
      const inputs = fs.readFileSync(req.inputs).toString('base64');
      const r = await session.call('blend', { ...req, inputs });
      fs.writeFileSync(req.out, Buffer.from(r.data, 'base64'));
      delete r.data;
      return r;
    }
    case 'screenshot': {
      await session.call('show', req);
      await session.page.locator('canvas#view').screenshot({ path: req.out });
      return { out: req.out };
    }
    case 'errors': {
      const e = session.errors.splice(0);
      return e;
    }
    case 'eval':
      return session.call(req.name, req.args || {});
    default:
      throw new Error(`unknown command ${req.cmd}`);
  }
}

const rl = readline.createInterface({ input: process.stdin });
for await (const line of rl) {
  if (!line.trim()) continue;
  let req;
  try {
    req = JSON.parse(line);
  } catch (e) {
    process.stdout.write(JSON.stringify({ ok: false, error: `bad request: ${e.message}` }) + '\n');
    continue;
  }
  if (req.cmd === 'quit') break;
  try {
    const result = await handle(req);
    process.stdout.write(JSON.stringify({ ok: true, result }) + '\n');
  } catch (e) {
    process.stdout.write(JSON.stringify({ ok: false, error: String(e && e.stack ? e.stack : e) }) + '\n');
  }
}
rl.close();
// never hang on the way out (a browser that does not close is killed with this process)
setTimeout(() => process.exit(0), 5000).unref();
await session.close();
process.exit(0);
