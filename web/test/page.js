// The test page: window.hhdTest functions that web/test/harness.mjs calls through playwright-core.
// Renders go into a float RGBA render target read back exactly (no tone mapping, no colour
// space conversion); rows are returned top row first.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

import { DEBUG, HHDLightmapPlugin } from '../src/HHDLightmapPlugin.js';
import { HHD_COMMON, blendGLSL } from '../src/shaders.js';

const canvas = document.getElementById('view');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
renderer.setPixelRatio(1);
renderer.toneMapping = THREE.NoToneMapping;

const state = { gltf: null, controls: null, loadErrors: [] };

const MODES = {
  shaded: DEBUG.OFF,
  stock: DEBUG.OFF,
  lightmap: DEBUG.LIGHTMAP,
  uv: DEBUG.UV,
  nv: DEBUG.NV,
  n: DEBUG.N,
  albedo: DEBUG.ALBEDO,
  hhd: DEBUG.HHD,
  dir: DEBUG.DIRECTION,
  irradiance: DEBUG.IRRADIANCE,
  probes: DEBUG.PROBES,
  probe_position: DEBUG.PROBE_POSITION,
  probe_n: DEBUG.PROBE_N,
  probe_albedo: DEBUG.PROBE_ALBEDO,
};

// What debug renders show for meshes the plugin does not touch: nothing (alpha 0), but they
// still hide what lies behind them.
const HIDDEN = new THREE.ShaderMaterial({
  vertexShader: 'void main() { gl_Position = projectionMatrix * modelViewMatrix * vec4(position, 1.0); }',
  fragmentShader: 'void main() { gl_FragColor = vec4(0.0); }',
});

function base64(typed) {
  const bytes = new Uint8Array(typed.buffer, typed.byteOffset, typed.byteLength);
  let s = '';
  for (let i = 0; i < bytes.length; i += 0x8000) s += String.fromCharCode.apply(null, bytes.subarray(i, i + 0x8000));
  return btoa(s);
}

function fromBase64(b64) {
  const s = atob(b64);
  const bytes = new Uint8Array(s.length);
  for (let i = 0; i < s.length; ++i) bytes[i] = s.charCodeAt(i);
  return new Float32Array(bytes.buffer);
}

async function load({ url, plugin = true, options = {} }) {
  const loader = new GLTFLoader();
  if (plugin) loader.register((parser) => new HHDLightmapPlugin(parser, options));
  state.gltf = null;
  state.controls = null;
  const gltf = await loader.loadAsync(url);
  state.gltf = gltf;
  state.plugin = plugin;
  state.controls = gltf.userData.hhdLightmap || null;
  state.original = new Map();
  gltf.scene.traverse((o) => {
    if (o.isMesh) state.original.set(o, o.material);
  });
  const meshes = [...state.original.keys()];
  const c = state.controls;
  return {
    cameras: gltf.cameras.length,
    camera: gltf.cameras[0]
      ? { name: gltf.cameras[0].name, fov: gltf.cameras[0].fov, aspect: gltf.cameras[0].aspect }
      : null,
    meshes: meshes.length,
    extension: !!(gltf.parser.json.extensions && gltf.parser.json.extensions.HHD_lightmap),
    extensionsUsed: gltf.parser.json.extensionsUsed || [],
    receivers: c ? c.receivers.length : 0,
    probeLit: c ? c.probeLit.length : 0,
    lightSets: c ? c.lightSets : [],
    warnings: c ? c.warnings : [],
    filter: c ? c.filter : null,
    emissiveMaps: meshes.filter((m) => [].concat(m.material).some((x) => x.emissiveMap)).length,
  };
}

function camera(width, height) {
  const gltf = state.gltf;
  let cam = gltf.cameras[0];
  if (!cam) {
    // no camera in the file: frame the scene's bounds
    const box = new THREE.Box3().setFromObject(gltf.scene);
    const centre = box.getCenter(new THREE.Vector3());
    const size = box.getSize(new THREE.Vector3()).length();
    cam = new THREE.PerspectiveCamera(50, width / height, size / 100, size * 10);
    cam.position.copy(centre).add(new THREE.Vector3(0.6, 0.5, 0.8).multiplyScalar(size));
    cam.lookAt(centre);
  }
  cam.aspect = width / height;
  cam.updateProjectionMatrix();
  gltf.scene.updateMatrixWorld(true);
  cam.updateMatrixWorld(true);
  return cam;
}

function prepare({ mode = 'lightmap', weights = null, blend = null }) {
  if (!(mode in MODES)) throw new Error(`unknown mode ${mode}`);
  const debug = MODES[mode];
  const c = state.controls;
  if (c) {
    c.setDebug(debug);
    if (blend !== null) c.setBlend(blend);
    if (weights) for (const [name, w] of Object.entries(weights)) c.setWeight(name, w);
  }
  for (const [mesh, material] of state.original) {
    const touched = mesh.userData.hhdReceiver || mesh.userData.hhdProbeLit;
    mesh.material = debug !== DEBUG.OFF && !touched ? HIDDEN : material;
  }
  // materials the plugin replaced are the meshes' current ones: keep them
  for (const [mesh] of state.original) {
    if (mesh.userData.hhdReceiver || mesh.userData.hhdProbeLit) state.original.set(mesh, mesh.material);
  }
}

function render({ mode = 'lightmap', width = 256, height = 256, weights = null, blend = null }) {
  prepare({ mode, weights, blend });
  const cam = camera(width, height);
  const target = new THREE.WebGLRenderTarget(width, height, {
    type: THREE.FloatType,
    format: THREE.RGBAFormat,
    minFilter: THREE.NearestFilter,
    magFilter: THREE.NearestFilter,
    depthBuffer: true,
    samples: 0,
  });
  renderer.setRenderTarget(target);
  renderer.setClearColor(0x000000, 0);
  renderer.clear();
  renderer.render(state.gltf.scene, cam);
  const pixels = new Float32Array(width * height * 4);
  renderer.readRenderTargetPixels(target, 0, 0, width, height, pixels);
  renderer.setRenderTarget(null);
  target.dispose();
  const flipped = new Float32Array(pixels.length); // top row first
  const row = width * 4;
  for (let y = 0; y < height; ++y) flipped.set(pixels.subarray(y * row, (y + 1) * row), (height - 1 - y) * row);
  let covered = 0;
  let nonBlack = 0;
  for (let i = 0; i < flipped.length; i += 4) {
    if (flipped[i + 3] > 0) covered++;
    if (flipped[i] + flipped[i + 1] + flipped[i + 2] > 1e-4) nonBlack++;
  }
  return { width, height, mode, covered, nonBlack, data: base64(flipped) };
}

/** The tone-mapped view on the page's canvas (make demo's preview_web.png). */
function show({ width = 640, height = 360, mode = 'shaded', toneMapping = 'agx', exposure = 1.0 }) {
  prepare({ mode });
  const cam = camera(width, height);
  renderer.setSize(width, height, true);
  renderer.toneMapping = { agx: THREE.AgXToneMapping, neutral: THREE.NeutralToneMapping, none: THREE.NoToneMapping }[
    toneMapping
  ];
  renderer.toneMappingExposure = exposure;
  renderer.setRenderTarget(null);
  renderer.setClearColor(0x000000, 1);
  renderer.clear();
  renderer.render(state.gltf.scene, cam);
  renderer.toneMapping = THREE.NoToneMapping;
  return { width, height };
}

/** The plugin's GLSL light-set blend over N synthetic texels. inputs: float32, blocks of N RGBA
 * texels each: [nv.xyz, 0], then per set k: [Iz.rgb, wa], [d.xyz, 0]. weights: K RGB triples.
 * Returns N × 8 floats: [Iz.rgb, wa, d.xyz, 0] of the blend. */
function blend({ inputs, sets, texels, weights }) {
  const data = fromBase64(inputs);
  const K = sets;
  const N = texels;
  const W = Math.min(N, 1024);
  const H = Math.ceil(N / W);
  const blocks = 1 + 2 * K;
  const padded = new Float32Array(W * H * blocks * 4);
  for (let b = 0; b < blocks; ++b) padded.set(data.subarray(b * N * 4, (b + 1) * N * 4), b * W * H * 4);
  const tex = new THREE.DataTexture(padded, W, H * blocks, THREE.RGBAFormat, THREE.FloatType);
  tex.minFilter = THREE.NearestFilter;
  tex.magFilter = THREE.NearestFilter;
  tex.needsUpdate = true;
  const uniforms = { inputs: { value: tex }, H: { value: H }, which: { value: 0 } };
  weights.forEach((w, k) => (uniforms[`w${k}`] = { value: new THREE.Vector3(...w) }));
  const reads = [];
  for (let k = 0; k < K; ++k) {
    reads.push(`{ vec4 a = texelFetch(inputs, p + ivec2(0, ${1 + 2 * k} * H), 0);
      vec4 b = texelFetch(inputs, p + ivec2(0, ${2 + 2 * k} * H), 0);
      sets[${k}] = HHDTexel(a.rgb, vec3(a.a), b.xyz); w[${k}] = w${k}; }`);
  }
  const material = new THREE.ShaderMaterial({
    uniforms,
    vertexShader: 'void main() { gl_Position = vec4(position.xy, 0.0, 1.0); }',
    fragmentShader: `
      precision highp float;
      precision highp sampler2D;
      ${HHD_COMMON}
      ${blendGLSL(K)}
      uniform sampler2D inputs;
      uniform int H;
      uniform int which;
      ${weights.map((_, k) => `uniform vec3 w${k};`).join('\n')}
      void main() {
        ivec2 p = ivec2(gl_FragCoord.xy);
        vec3 nv = texelFetch(inputs, p, 0).xyz;
        HHDTexel sets[${K}];
        vec3 w[${K}];
        ${reads.join('\n')}
        HHDTexel h = hhdBlend${K}(sets, w, nv);
        gl_FragColor = which == 0 ? vec4(h.Iz, h.wa.r) : vec4(h.d, 0.0);
      }`,
  });
  const scene = new THREE.Scene();
  const quad = new THREE.Mesh(new THREE.PlaneGeometry(2, 2), material);
  quad.frustumCulled = false;
  scene.add(quad);
  const cam = new THREE.OrthographicCamera(-1, 1, 1, -1, 0, 1);
  const target = new THREE.WebGLRenderTarget(W, H, { type: THREE.FloatType, minFilter: THREE.NearestFilter, magFilter: THREE.NearestFilter });
  const out = new Float32Array(N * 8);
  const px = new Float32Array(W * H * 4);
  for (const which of [0, 1]) {
    uniforms.which.value = which;
    renderer.setRenderTarget(target);
    renderer.render(scene, cam);
    renderer.readRenderTargetPixels(target, 0, 0, W, H, px);
    for (let i = 0; i < N; ++i) for (let c = 0; c < 4; ++c) out[i * 8 + which * 4 + c] = px[i * 4 + c];
  }
  renderer.setRenderTarget(null);
  target.dispose();
  tex.dispose();
  material.dispose();
  return { texels: N, data: base64(out) };
}

function info() {
  const gl = renderer.getContext();
  const dbg = gl.getExtension('WEBGL_debug_renderer_info');
  return {
    webgl2: renderer.capabilities.isWebGL2 !== false,
    renderer: dbg ? gl.getParameter(dbg.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER),
    floatTargets: !!gl.getExtension('EXT_color_buffer_float'),
    three: THREE.REVISION,
  };
}

window.hhdTest = { ready: true, info, load, render, show, blend };
