// The browser side of the tests and of `make demo`'s web preview: a local HTTP server over web/
// (plus the files a caller mounts), Debian's Chromium driven by playwright-core (never a
// downloaded browser build), WebGL2 on SwiftShader, and the test page web/test/page.html whose
// window.hhdTest functions load a .glb and render it.
import { execFileSync } from 'node:child_process';
import fs from 'node:fs';
import http from 'node:http';
import path from 'node:path';
import { fileURLToPath } from 'node:url';

import { chromium } from 'playwright-core';

export const WEB_ROOT = path.resolve(path.dirname(fileURLToPath(import.meta.url)), '..');

// --no-sandbox: CI and containers run as root, where Chromium's sandbox refuses to start.
export const CHROMIUM_ARGS = [
  '--headless=new',
  '--use-angle=swiftshader',
  '--enable-unsafe-swiftshader',
  '--ignore-gpu-blocklist',
  '--no-sandbox',
  '--disable-dev-shm-usage',
];

export const HOW_TO_GET_CHROMIUM =
  'no Chromium found: install Debian\'s package (`sudo apt-get install chromium`) or set HHD_CHROMIUM=/path/to/chromium';

/** The Chromium to drive: $HHD_CHROMIUM, else the first of the usual Debian/Ubuntu names on PATH. */
export function findChromium() {
  if (process.env.HHD_CHROMIUM) return fs.existsSync(process.env.HHD_CHROMIUM) ? process.env.HHD_CHROMIUM : null;
  for (const name of ['/usr/bin/chromium', 'chromium', 'chromium-browser', 'google-chrome']) {
    if (path.isAbsolute(name)) {
      if (fs.existsSync(name)) return name;
      continue;
    }
    try {
      return execFileSync('which', [name], { encoding: 'utf8' }).trim() || null;
    } catch {
      // not on PATH
    }
  }
  return null;
}

const TYPES = {
  '.html': 'text/html; charset=utf-8',
  '.js': 'text/javascript; charset=utf-8',
  '.mjs': 'text/javascript; charset=utf-8',
  '.json': 'application/json',
  '.glb': 'model/gltf-binary',
  '.gltf': 'model/gltf+json',
  '.bin': 'application/octet-stream',
  '.png': 'image/png',
  '.jpg': 'image/jpeg',
  '.ktx2': 'image/ktx2',
  '.webp': 'image/webp',
};

/** A static server on 127.0.0.1 (a free port) over WEB_ROOT; `mount(file)` serves a file from
 * elsewhere (its folder, so a .gltf's .bin and images come along) and returns its URL. */
export async function startServer(root = WEB_ROOT) {
  const mounts = new Map(); // token -> folder
  const server = http.createServer((req, res) => {
    const url = new URL(req.url, 'http://localhost');
    let file;
    const m = url.pathname.match(/^\/mount\/(\d+)\/(.*)$/);
    if (m && mounts.has(m[1])) {
      file = path.join(mounts.get(m[1]), decodeURIComponent(m[2]));
      if (!file.startsWith(mounts.get(m[1]))) file = null;
    } else {
      file = path.join(root, decodeURIComponent(url.pathname));
      if (!file.startsWith(root)) file = null;
    }
    if (file && fs.existsSync(file) && fs.statSync(file).isDirectory()) file = path.join(file, 'index.html');
    if (!file || !fs.existsSync(file)) {
      res.writeHead(404);
      res.end('not found');
      return;
    }
    res.writeHead(200, {
      'Content-Type': TYPES[path.extname(file).toLowerCase()] || 'application/octet-stream',
      'Cache-Control': 'no-store',
    });
    fs.createReadStream(file).pipe(res);
  });
  await new Promise((resolve) => server.listen(0, '127.0.0.1', resolve));
  const base = `http://127.0.0.1:${server.address().port}`;
  return {
    base,
    mount(file) {
      const folder = path.dirname(path.resolve(file));
      let token = [...mounts].find(([, f]) => f === folder)?.[0];
      if (!token) {
        token = String(mounts.size + 1);
        mounts.set(token, folder);
      }
      return `${base}/mount/${token}/${encodeURIComponent(path.basename(file))}`;
    },
    close: () =>
      new Promise((resolve) => {
        server.closeAllConnections(); // Chromium keeps its connections alive
        server.close(resolve);
      }),
  };
}

/** Chromium on the test page. Returns { page, server, call(name, args), close() }; `call` runs
 * window.hhdTest[name](args) in the page and returns its result; page errors are collected in
 * `errors` (console errors and uncaught exceptions). */
export async function openSession({ chromiumPath = findChromium(), log = () => {} } = {}) {
  if (!chromiumPath) throw new Error(HOW_TO_GET_CHROMIUM);
  const server = await startServer();
  const browser = await chromium.launch({ executablePath: chromiumPath, args: CHROMIUM_ARGS, headless: true });
  const page = await browser.newPage();
  const errors = [];
  page.on('console', (msg) => {
    if (msg.type() === 'error' || msg.type() === 'warning') errors.push(`${msg.type()}: ${msg.text()}`);
    log(`[page ${msg.type()}] ${msg.text()}`);
  });
  page.on('pageerror', (err) => errors.push(`pageerror: ${err.message}`));
  await page.goto(`${server.base}/test/page.html`);
  await page.waitForFunction(() => window.hhdTest && window.hhdTest.ready, null, { timeout: 60000 });
  const info = await page.evaluate(() => window.hhdTest.info());
  return {
    page,
    server,
    errors,
    info,
    version: browser.version(),
    async call(name, args = {}) {
      return page.evaluate(([n, a]) => window.hhdTest[n](a), [name, args]);
    },
    async close() {
      await browser.close();
      await server.close();
    },
  };
}

/** Decodes the page's base64 float32 arrays. */
export function floats(b64) {
  const buf = Buffer.from(b64, 'base64');
  return new Float32Array(buf.buffer, buf.byteOffset, buf.byteLength / 4);
}
