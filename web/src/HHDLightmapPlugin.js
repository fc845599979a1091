// three.js GLTFLoader plugin for the HHD_lightmap extension (docs/gltf.md): directional HHD
// lightmaps reconstructed per pixel at the normal-mapped normal, light sets blended live through
// linear SH (weights are uniforms), and probe-volume irradiance (trilinear L2 SH) for meshes
// without a lightmap.
//
//   const loader = new GLTFLoader().register((parser) => new HHDLightmapPlugin(parser));
//   const gltf = await loader.loadAsync('level.glb');   // gltf.userData.hhdLightmap: the controls
//   new HHDLightmapPlugin(parser, { filter: 'bicubic' })  // Catmull-Rom I_z and w_a (default: the file's hint)
//
// Receivers keep their MeshStandardMaterial / MeshPhysicalMaterial (their lights, normal maps,
// specular and environment still work); `onBeforeCompile` replaces three.js's lightmap term with
// the HHD reconstruction and turns off the exporter's emissive fallback.
import {
  DataTexture,
  FloatType,
  Matrix4,
  NearestFilter,
  RGBAFormat,
  ShaderChunk,
  Vector3,
} from 'three';

import { HHD_COMMON, blendGLSL } from './shaders.js';

export const EXTENSION = 'HHD_lightmap';

/** What a receiver shows; DEBUG.LIGHTMAP and the G-buffer modes are what the tests read back
 * (linear floats into a float render target, written after tone mapping and colour space). */
export const DEBUG = Object.freeze({
  OFF: 0, //  the material's full shading, HHD irradiance as its indirect diffuse
  LIGHTMAP: 1, // albedo × I (project units: the outgoing radiance of the baked lighting), alpha 1
  UV: 2, //  lightmap atlas UV (glTF convention, after scaleOffset), atlas index, 1
  NV: 3, //  interpolated vertex normal n_v, glTF world, 1
  N: 4, //  shading (normal-mapped) normal n, glTF world, 1
  ALBEDO: 5, // base colour (linear), 1
  HHD: 6, //  the HHD parameters the reconstruction used (after the blend): I_z RGB, w_a (luminance / R)
  DIRECTION: 7, // their direction d, glTF world, 1
  IRRADIANCE: 8, // I (project units), 1
  PROBES: 9, // albedo × probe irradiance on the meshes the probe volumes light (alpha 0 elsewhere)
  PROBE_POSITION: 10, // their world position (glTF), 1
  PROBE_N: 11, // their shading normal, 1
  PROBE_ALBEDO: 12, // their base colour, 1
});

// The I_z packings of docs/gltf.md ("Packed"), per texel, as core/encoding/web_packing.py
// `decode` (the reference): c = the RGBA texel / 255, range = the packing's scale in I units.
const PACKINGS = {
  rgbm: 'c.rgb * c.a * range',
  rgbd: 'c.rgb / max(c.a, 1.0 / 255.0) * (range / 255.0)',
  logluv: 'hhdLogLuv(c, range)',
};

// LogLuv: luminance Y = 2^(L16/65535 · 32 − 32) · range (L16 = 256·b + a bytes, 0 = black),
// chromaticity u' = r · 0.62, v' = g · 0.62 (CIE 1976), XYZ → linear Rec.709.
const LOGLUV_GLSL = /* glsl */ `
vec3 hhdLogLuv(vec4 c, float range) {
  const float STOPS = 32.0, U_MAX = 0.62;
  float l16 = floor(c.b * 255.0 + 0.5) * 256.0 + floor(c.a * 255.0 + 0.5);
  float Y = l16 > 0.0 ? exp2(l16 / 65535.0 * STOPS - STOPS) * range : 0.0;
  float u = c.r * U_MAX, v = max(c.g * U_MAX, 1e-6);
  vec3 xyz = vec3(Y * 9.0 * u / (4.0 * v), Y, Y * (12.0 - 3.0 * u - 20.0 * v) / (4.0 * v));
  const mat3 XYZ_TO_RGB = mat3(3.2404548, -0.9692664, 0.0556434, -1.5371389, 1.8760109, -0.2040259,
                               -0.4985315, 0.0415561, 1.0572252);
  return max(XYZ_TO_RGB * xyz, 0.0);
}
`;

function packingGLSL(name) {
  const expr = PACKINGS[name];
  if (!expr) throw new Error(`${EXTENSION}: unknown packing '${name}'`);
  return `vec3 hhdUnpack_${name}(vec4 c, float range) { return ${expr}; }\n`;
}

// Bilinear filtering of decoded texels (the packings are not linear: docs/gltf.md "Filtering"):
// the four texels around uv (texel centres at (x + ½)/w), clamped to the edge.
const FETCH_GLSL = /* glsl */ `
#define HHD_BILINEAR(NAME, TEX, DECODE)                                                          \\
vec3 NAME(vec2 uv, float range) {                                                                \\
  ivec2 size = textureSize(TEX, 0);                                                              \\
  vec2 p = uv * vec2(size) - 0.5;                                                                \\
  vec2 fl = floor(p);                                                                            \\
  vec2 f = p - fl;                                                                               \\
  ivec2 i0 = clamp(ivec2(fl), ivec2(0), size - 1);                                               \\
  ivec2 i1 = clamp(ivec2(fl) + 1, ivec2(0), size - 1);                                           \\
  vec3 a = DECODE(texelFetch(TEX, ivec2(i0.x, i0.y), 0), range);                                \\
  vec3 b = DECODE(texelFetch(TEX, ivec2(i1.x, i0.y), 0), range);                                \\
  vec3 c = DECODE(texelFetch(TEX, ivec2(i0.x, i1.y), 0), range);                                \\
  vec3 d = DECODE(texelFetch(TEX, ivec2(i1.x, i1.y), 0), range);                                \\
  return mix(mix(a, b, f.x), mix(c, d, f.x), f.y);                                               \\
}
vec4 hhdBilinearRaw(sampler2D tex, vec2 uv) {                    // unorm8 data that is linear (w_a)
  ivec2 size = textureSize(tex, 0);
  vec2 p = uv * vec2(size) - 0.5;
  vec2 fl = floor(p);
  vec2 f = p - fl;
  ivec2 i0 = clamp(ivec2(fl), ivec2(0), size - 1);
  ivec2 i1 = clamp(ivec2(fl) + 1, ivec2(0), size - 1);
  vec4 a = texelFetch(tex, ivec2(i0.x, i0.y), 0), b = texelFetch(tex, ivec2(i1.x, i0.y), 0);
  vec4 c = texelFetch(tex, ivec2(i0.x, i1.y), 0), d = texelFetch(tex, ivec2(i1.x, i1.y), 0);
  return mix(mix(a, b, f.x), mix(c, d, f.x), f.y);
}
vec3 hhdWorld(vec3 viewDir) { return normalize((vec4(viewDir, 0.0) * viewMatrix).xyz); }
`;

// The `filter: 'bicubic'` option (docs/format.md "Bicubic sampling"): Catmull-Rom over the 4 × 4
// texels around uv, each texel decoded first (the packings are not linear, so docs/format.md's
// 9-tap form, which lets the hardware blend pairs of texels, would blend encoded bytes here): 16
// texelFetch, the same weights as the 9 taps (they merge the middle two texels of each axis
// exactly). Indices clamped to the edge as core.textures.sample_bicubic(clamp=True); the caller
// clamps the result (I_z ≥ 0 inside HHD_BICUBIC, w_a to [0, 1] in readLayerGLSL).
const BICUBIC_GLSL = /* glsl */ `
vec4 hhdCatmullRom(float t) {   // weights of the texels at offsets -1, 0, 1, 2 from t in [0, 1)
  return vec4(t * (-0.5 + t * (1.0 - 0.5 * t)), 1.0 + t * t * (-2.5 + 1.5 * t),
              t * (0.5 + t * (2.0 - 1.5 * t)), t * t * (-0.5 + 0.5 * t));
}
#define HHD_BICUBIC(NAME, TEX, DECODE)                                                           \\
vec3 NAME(vec2 uv, float range) {                                                                \\
  ivec2 size = textureSize(TEX, 0);                                                              \\
  vec2 p = uv * vec2(size) - 0.5;                                                                \\
  vec2 fl = floor(p);                                                                            \\
  vec4 wx = hhdCatmullRom(p.x - fl.x), wy = hhdCatmullRom(p.y - fl.y);                           \\
  ivec2 i0 = ivec2(fl) - 1;                                                                      \\
  vec3 s = vec3(0.0);                                                                            \\
  for (int j = 0; j < 4; ++j) {                                                                  \\
    int y = clamp(i0.y + j, 0, size.y - 1);                                                      \\
    vec3 row = vec3(0.0);                                                                        \\
    for (int i = 0; i < 4; ++i)                                                                  \\
      row += wx[i] * DECODE(texelFetch(TEX, ivec2(clamp(i0.x + i, 0, size.x - 1), y), 0), range); \\
    s += wy[j] * row;                                                                            \\
  }                                                                                              \\
  return max(s, 0.0);                                                                            \\
}
vec4 hhdBicubicRaw(sampler2D tex, vec2 uv) {                     // unorm8 data that is linear (w_a)
  ivec2 size = textureSize(tex, 0);
  vec2 p = uv * vec2(size) - 0.5;
  vec2 fl = floor(p);
  vec4 wx = hhdCatmullRom(p.x - fl.x), wy = hhdCatmullRom(p.y - fl.y);
  ivec2 i0 = ivec2(fl) - 1;
  vec4 s = vec4(0.0);
  for (int j = 0; j < 4; ++j) {
    int y = clamp(i0.y + j, 0, size.y - 1);
    vec4 row = vec4(0.0);
    for (int i = 0; i < 4; ++i) row += wx[i] * texelFetch(tex, ivec2(clamp(i0.x + i, 0, size.x - 1), y), 0);
    s += wy[j] * row;
  }
  return s;
}
`;

/** The lightmap filters the plugin knows (option `filter`, the file's root `filter` hint). */
export const FILTERS = Object.freeze(['bilinear', 'bicubic']);

// The direction d: each of the four texels decoded to a unit vector (octahedral), the vectors
// blended with the bilinear weights and normalised (docs/gltf.md "Filtering"). Blending the
// encoded bytes instead is wrong where the octahedral map folds (directions near the lower
// hemisphere's edge: neighbouring texels far apart in the encoding average to a wrong direction).
// `channels`: the two channels holding the encoding ("rg"). A blend of length ~0 (opposite
// directions, equal weights) falls back to the first texel's direction.
function directionGLSL(name, tex, channels) {
  const dec = (i) => `hhdOctDecode(vec2(texelFetch(${tex}, ${i}, 0).${channels}) * 2.0 - 1.0)`;
  return /* glsl */ `
vec3 ${name}(vec2 uv) {
  ivec2 size = textureSize(${tex}, 0);
  vec2 p = uv * vec2(size) - 0.5;
  vec2 fl = floor(p);
  vec2 f = p - fl;
  ivec2 i0 = clamp(ivec2(fl), ivec2(0), size - 1);
  ivec2 i1 = clamp(ivec2(fl) + 1, ivec2(0), size - 1);
  vec3 a = ${dec('ivec2(i0.x, i0.y)')}, b = ${dec('ivec2(i1.x, i0.y)')};
  vec3 c = ${dec('ivec2(i0.x, i1.y)')}, d = ${dec('ivec2(i1.x, i1.y)')};
  vec3 s = mix(mix(a, b, f.x), mix(c, d, f.x), f.y);
  float len = length(s);
  return len > 1e-6 ? s / len : a;
}
`;
}

const CHANNELS = { r: 0, g: 1, b: 2, a: 3 };

/** GLSL that reads one layer set (I_z, w_a, d) into an HHDTexel `dst` at `uv`; `bicubic`: I_z
 * and w_a Catmull-Rom (clamped: I_z ≥ 0, w_a in [0, 1]), d bilinear either way. */
function readLayerGLSL(layer, dst, uv, bicubic) {
  const { prefix, packing, waChannels, dirChannels, waSeparate } = layer;
  const wa = `${bicubic ? 'hhdBicubicRaw' : 'hhdBilinearRaw'}(${waSeparate ? `${prefix}Wa` : `${prefix}Dir`}, ${uv})`;
  let waExpr =
    waChannels.length === 3
      ? `${wa}.${waChannels}`
      : `vec3(${wa}.${waChannels})`;
  if (bicubic) waExpr = `clamp(${waExpr}, 0.0, 1.0)`;
  return `
  {
    ${dst}.Iz = ${prefix}Iz_${packing}(${uv}, ${prefix}Range);
    ${dst}.wa = ${waExpr};
    ${dst}.d = ${prefix}Dir_oct(${uv});
  }`;
}

function layerDeclGLSL(layer, bicubic) {
  const { prefix, packing, waSeparate, dirChannels } = layer;
  if (!/^[rgba]{2}$/.test(dirChannels)) throw new Error(`${EXTENSION}: direction channels '${dirChannels}'`);
  return `
uniform sampler2D ${prefix}Iz;
uniform sampler2D ${prefix}Dir;
${waSeparate ? `uniform sampler2D ${prefix}Wa;` : ''}
uniform float ${prefix}Range;
${bicubic ? 'HHD_BICUBIC' : 'HHD_BILINEAR'}(${prefix}Iz_${packing}, ${prefix}Iz, hhdUnpack_${packing})
${directionGLSL(`${prefix}Dir_oct`, `${prefix}Dir`, dirChannels)}`;
}

/** The fragment code that replaces three.js's lightmap term (docs/format.md, "Reconstruction"). */
function receiverGLSL(spec) {
  const { layers, sets, ahd, selfBounce, filter } = spec;
  const bicubic = filter === 'bicubic';
  const packings = [...new Set(layers.map((l) => l.packing).concat(sets.map((s) => s.packing)))];
  let decl = `${HHD_COMMON}\n${packings.includes('logluv') ? LOGLUV_GLSL : ''}${packings.map(packingGLSL).join('')}${FETCH_GLSL}`;
  if (bicubic) decl += BICUBIC_GLSL;
  decl += layers.map((l) => layerDeclGLSL(l, bicubic)).join('');
  decl += sets.map((s) => layerDeclGLSL(s, bicubic)).join('');
  decl += `uniform int hhdDebug;\nuniform float hhdAtlasIndex;\n`;
  if (sets.length) {
    decl += sets.map((s, i) => `uniform vec3 hhdSetWeight${i};\n`).join('');
    decl += `uniform bool hhdBlendSets;\n${blendGLSL(sets.length)}`;
  }
  let body = `
  vec2 hhdUv = vLightMapUv;
  vec3 hhdNv = hhdWorld(nonPerturbedNormal);
  vec3 hhdN = hhdWorld(normal);
  HHDTexel hhdTexel;
  ${readLayerGLSL(layers[0], 'hhdTexel', 'hhdUv', bicubic)}`;
  if (sets.length) {
    body += `
  if (hhdBlendSets) {
    HHDTexel hhdSets[${sets.length}];
    vec3 hhdW[${sets.length}];
    ${sets.map((s, i) => readLayerGLSL(s, `hhdSets[${i}]`, 'hhdUv', bicubic) + `\n    hhdW[${i}] = hhdSetWeight${i};`).join('\n')}
    hhdTexel = hhdBlend${sets.length}(hhdSets, hhdW, hhdNv);
  }`;
  }
  body += `
  vec3 hhdI = hhdIrradiance(hhdTexel, hhdNv, hhdN, ${ahd ? 'true' : 'false'});
  ${selfBounce ? 'hhdI += diffuseColor.rgb * hhdTexel.Iz * 0.5 * (1.0 - dot(hhdN, hhdNv));' : ''}
  #if defined( RE_IndirectDiffuse )
    irradiance += hhdI * lightMapIntensity;   // three.js irradiance = π × I (lightMapIntensity = π)
  #endif
`;
  const debug = `
  if (hhdDebug > 0) {
    vec4 o = vec4(0.0, 0.0, 0.0, 1.0);
    if (hhdDebug == ${DEBUG.LIGHTMAP}) o.rgb = diffuseColor.rgb * hhdI;
    else if (hhdDebug == ${DEBUG.UV}) o = vec4(hhdUv, hhdAtlasIndex, 1.0);
    else if (hhdDebug == ${DEBUG.NV}) o.rgb = hhdNv;
    else if (hhdDebug == ${DEBUG.N}) o.rgb = hhdN;
    else if (hhdDebug == ${DEBUG.ALBEDO}) o.rgb = diffuseColor.rgb;
    else if (hhdDebug == ${DEBUG.HHD}) o = vec4(hhdTexel.Iz, hhdTexel.wa.r);
    else if (hhdDebug == ${DEBUG.DIRECTION}) o.rgb = hhdTexel.d;
    else if (hhdDebug == ${DEBUG.IRRADIANCE}) o.rgb = hhdI;
    else o = vec4(0.0);
    gl_FragColor = o;
  }
`;
  return { decl, body, debug };
}

// --- probe volumes ---------------------------------------------------------------------------

const MAX_VOLUMES = 4;

function probeGLSL(volumes) {
  let decl = `${HHD_COMMON}\n${FETCH_GLSL}uniform int hhdDebug;\n`;
  volumes.forEach((v, i) => {
    decl += `uniform sampler2D hhdProbe${i};\nuniform mat4 hhdProbeToLocal${i};\nuniform vec3 hhdProbeRes${i};\n`;
  });
  decl += /* glsl */ `
vec3 hhdProbeFetch(sampler2D tex, ivec3 c, vec3 res, int k) {
  int p = c.x + int(res.x) * (c.y + int(res.y) * c.z);
  int w = textureSize(tex, 0).x;
  return texelFetch(tex, ivec2(p % w, k + 9 * (p / w)), 0).rgb;
}
// trilinear between probe centres, clamped to the outermost probes; weight 0 outside the volume
float hhdProbeSample(sampler2D tex, mat4 toLocal, vec3 res, vec3 world, out vec3 sh[9]) {
  vec3 local = (toLocal * vec4(world, 1.0)).xyz;
  vec3 q = (local * 0.5 + 0.5) * res - 0.5;
  vec3 fl = floor(q);
  vec3 f = clamp(q - fl, 0.0, 1.0);
  ivec3 i0 = clamp(ivec3(fl), ivec3(0), ivec3(res) - 1);
  ivec3 i1 = clamp(ivec3(fl) + 1, ivec3(0), ivec3(res) - 1);
  for (int k = 0; k < 9; ++k) {
    vec3 c000 = hhdProbeFetch(tex, ivec3(i0.x, i0.y, i0.z), res, k), c100 = hhdProbeFetch(tex, ivec3(i1.x, i0.y, i0.z), res, k);
    vec3 c010 = hhdProbeFetch(tex, ivec3(i0.x, i1.y, i0.z), res, k), c110 = hhdProbeFetch(tex, ivec3(i1.x, i1.y, i0.z), res, k);
    vec3 c001 = hhdProbeFetch(tex, ivec3(i0.x, i0.y, i1.z), res, k), c101 = hhdProbeFetch(tex, ivec3(i1.x, i0.y, i1.z), res, k);
    vec3 c011 = hhdProbeFetch(tex, ivec3(i0.x, i1.y, i1.z), res, k), c111 = hhdProbeFetch(tex, ivec3(i1.x, i1.y, i1.z), res, k);
    sh[k] = mix(mix(mix(c000, c100, f.x), mix(c010, c110, f.x), f.y), mix(mix(c001, c101, f.x), mix(c011, c111, f.x), f.y), f.z);
  }
  vec3 out3 = abs(local);
  return max(max(out3.x, out3.y), out3.z) <= 1.0 ? 1.0 : 0.0;
}
`;
  let body = `
  vec3 hhdWorldPos = (inverse(viewMatrix) * vec4(-vViewPosition, 1.0)).xyz;
  vec3 hhdN = hhdWorld(normal);
  vec3 hhdI = vec3(0.0);
  float hhdFound = 0.0;
  vec3 hhdSH[9];
`;
  volumes.forEach((v, i) => {
    body += `
  if (hhdFound == 0.0) {
    hhdFound = hhdProbeSample(hhdProbe${i}, hhdProbeToLocal${i}, hhdProbeRes${i}, hhdWorldPos, hhdSH);
    if (hhdFound > 0.0) hhdI = max(hhdSHIrradiance(hhdSH, hhdN), 0.0);
  }`;
  });
  body += `
  #if defined( RE_IndirectDiffuse )
    irradiance += hhdI * 3.141592653589793;   // three.js irradiance = π × I
  #endif
`;
  // debug: PROBES = albedo × probe irradiance, PROBE_POSITION / PROBE_N / PROBE_ALBEDO what a
  // reference needs; alpha 0 outside the volumes and in every receiver mode
  const debug = `
  if (hhdDebug > 0) {
    vec4 o = vec4(0.0, 0.0, 0.0, hhdFound);
    if (hhdDebug == ${DEBUG.PROBES}) o.rgb = diffuseColor.rgb * hhdI;
    else if (hhdDebug == ${DEBUG.PROBE_POSITION}) o.rgb = hhdWorldPos;
    else if (hhdDebug == ${DEBUG.PROBE_N}) o.rgb = hhdN;
    else if (hhdDebug == ${DEBUG.PROBE_ALBEDO}) o.rgb = diffuseColor.rgb;
    else o = vec4(0.0);
    gl_FragColor = o;
  }
`;
  return { decl, body, debug };
}

// --- material patching -----------------------------------------------------------------------

const MAPS_WITHOUT_LIGHTMAP = ShaderChunk.lights_fragment_maps.replace(/#ifdef USE_LIGHTMAP[\s\S]*?#endif/, '');

function patchMaterial(material, glsl, uniforms, cacheKey) {
  material.onBeforeCompile = (shader) => {
    Object.assign(shader.uniforms, uniforms);
    shader.fragmentShader = shader.fragmentShader
      .replace('#include <common>', `#include <common>\n${glsl.decl}`)
      .replace('#include <lights_fragment_maps>', `${glsl.body}\n${MAPS_WITHOUT_LIGHTMAP}`)
      .replace('#include <dithering_fragment>', `#include <dithering_fragment>\n${glsl.debug}`);
  };
  material.customProgramCacheKey = () => cacheKey;
  material.needsUpdate = true;
}

function isPatchable(material) {
  return material && (material.isMeshStandardMaterial || material.isMeshPhysicalMaterial);
}

// --- the plugin ------------------------------------------------------------------------------

/** The controls of one loaded file, `gltf.userData.hhdLightmap`. */
export class HHDLightmapControls {
  constructor(root) {
    this.root = root;
    this.receivers = []; // { object, node, atlas }
    this.probeLit = []; // meshes lit by the probe volumes
    this.warnings = [];
    this.uniforms = {
      hhdDebug: { value: DEBUG.OFF },
      hhdBlendSets: { value: (root.lightSets || []).length > 0 },
    };
    this.filter = 'bilinear'; // the lightmap filter the receivers use (FILTERS; the plugin sets it)
    this.lightSets = (root.lightSets || []).map((s) => s.name);
    this.weights = (root.lightSets || []).map((s) => new Vector3(...(s.weight || [1, 1, 1])));
  }

  /** DEBUG mode of every receiver (and probe-lit mesh). */
  setDebug(mode) {
    this.uniforms.hhdDebug.value = mode;
  }

  /** Live light-set blending on or off (off: the atlas's own layers, the state the .blend had). */
  setBlend(on) {
    this.uniforms.hhdBlendSets.value = !!on && this.weights.length > 0;
  }

  /** RGB (or scalar) weight of a light set by name or index; animate it freely. */
  setWeight(set, rgb) {
    const i = typeof set === 'number' ? set : this.lightSets.indexOf(set);
    if (i < 0 || i >= this.weights.length) throw new Error(`${EXTENSION}: no light set ${set}`);
    const v = typeof rgb === 'number' ? [rgb, rgb, rgb] : rgb;
    this.weights[i].set(v[0], v[1], v[2]);
  }
}

export class HHDLightmapPlugin {
  /** options: { selfBounce: false, probes: true, lightSets: true, filter: undefined }; `filter`
   * ('bilinear' | 'bicubic', FILTERS) overrides the file's hint (root `filter`, written by the
   * exporter); neither: bilinear. */
  constructor(parser, options = {}) {
    this.name = EXTENSION;
    this.parser = parser;
    this.options = { selfBounce: false, probes: true, lightSets: true, filter: undefined, ...options };
    const f = this.options.filter;
    if (f !== undefined && f !== null && !FILTERS.includes(f)) {
      throw new Error(`${EXTENSION}: unknown filter '${f}' (one of ${FILTERS.join(', ')})`);
    }
  }

  /** The filter the receivers use: the option, else the file's hint, else bilinear. */
  resolveFilter(root, controls) {
    if (this.options.filter) return this.options.filter;
    if (root.filter === undefined) return 'bilinear';
    if (FILTERS.includes(root.filter)) return root.filter;
    controls.warnings.push(`unknown filter '${root.filter}' in the file: bilinear`);
    return 'bilinear';
  }

  async afterRoot(result) {
    const parser = this.parser;
    const json = parser.json;
    const root = json.extensions && json.extensions[EXTENSION];
    if (!root) return;
    if (root.version !== 1) console.warn(`${EXTENSION}: version ${root.version}, this runtime reads 1`);
    const controls = new HHDLightmapControls(root);
    if (!this.options.lightSets) controls.setBlend(false);
    controls.filter = this.resolveFilter(root, controls);
    result.userData = result.userData || {};
    result.userData.hhdLightmap = controls;

    const textureCache = new Map();
    const texture = async (index) => {
      if (!textureCache.has(index)) {
        textureCache.set(
          index,
          parser.getDependency('texture', index).then((t) => {
            const tex = t.clone(); // data, read with texelFetch: no mips, no filtering, linear
            tex.generateMipmaps = false;
            tex.minFilter = NearestFilter;
            tex.magFilter = NearestFilter;
            tex.colorSpace = '';
            tex.flipY = false;
            tex.needsUpdate = true;
            return tex;
          }),
        );
      }
      return textureCache.get(index);
    };

    // Every layer (I_z, w_a, d) of an atlas or a set, as the GLSL reads it, and its uniforms.
    const layer = async (prefix, def) => {
      const waSeparate = def.ambientWeight.index !== def.direction.index;
      const uniforms = {
        [`${prefix}Iz`]: { value: await texture(def.irradiance.index) },
        [`${prefix}Dir`]: { value: await texture(def.direction.index) },
        [`${prefix}Range`]: { value: def.irradiance.range },
      };
      if (waSeparate) uniforms[`${prefix}Wa`] = { value: await texture(def.ambientWeight.index) };
      return {
        glsl: {
          prefix,
          packing: def.irradiance.packing,
          waChannels: def.ambientWeight.channels,
          dirChannels: def.direction.channels || 'rg',
          waSeparate,
        },
        uniforms,
      };
    };

    const atlases = root.atlases || [];
    const atlasLayers = [];
    for (let a = 0; a < atlases.length; ++a) {
      const atlas = atlases[a];
      const main = await layer('hhdA', atlas);
      const sets = [];
      if (this.options.lightSets) {
        for (const s of atlas.lightSets || []) sets.push(await layer(`hhdS${s.set}_`, s));
      }
      atlasLayers.push({ main, sets, setIndex: (atlas.lightSets || []).map((s) => s.set) });
    }

    // Receivers: every node with the extension, wherever it sits in the scene.
    const receiverMeshes = new Set();
    const patched = new Map(); // material uuid + key -> clone
    const nodeMeshes = (object) => {
      if (object.isMesh) return [object];
      return object.children.filter((c) => {
        const assoc = parser.associations.get(c);
        return c.isMesh && assoc && assoc.nodes === undefined;
      });
    };
    const receiverNodes = [];
    result.scene.traverse((object) => {
      const assoc = parser.associations.get(object);
      if (!assoc || assoc.nodes === undefined) return;
      const nodeDef = json.nodes[assoc.nodes];
      const ext = nodeDef.extensions && nodeDef.extensions[EXTENSION];
      if (ext) receiverNodes.push({ object, ext, node: assoc.nodes });
    });
    for (const { object, ext, node } of receiverNodes) {
      const atlas = atlases[ext.atlas];
      if (!atlas) {
        controls.warnings.push(`node ${node}: atlas ${ext.atlas} missing`);
        continue;
      }
      const k = ext.texCoord;
      if (!(k >= 0 && k <= 3)) {
        controls.warnings.push(`node ${node}: TEXCOORD_${k} is beyond three.js's four UV sets`);
        continue;
      }
      const [sx, sy, ox, oy] = ext.scaleOffset || [1, 1, 0, 0];
      const { main, sets, setIndex } = atlasLayers[ext.atlas];
      for (const mesh of nodeMeshes(object)) {
        const attr = k === 0 ? 'uv' : `uv${k}`;
        if (!mesh.geometry.getAttribute(attr)) {
          controls.warnings.push(`node ${node}: mesh '${mesh.name}' has no TEXCOORD_${k}`);
          continue;
        }
        const materials = Array.isArray(mesh.material) ? mesh.material : [mesh.material];
        const out = materials.map((material) => {
          if (!isPatchable(material)) {
            controls.warnings.push(`node ${node}: material '${material && material.name}' is not a MeshStandardMaterial`);
            return material;
          }
          const key = `${material.uuid}|${ext.atlas}|${k}|${sx},${sy},${ox},${oy}`;
          if (patched.has(key)) return patched.get(key);
          const m = material.clone();
          // the exporter's fallback for stock viewers: off (docs/gltf.md, "Material")
          const matIndex = parser.associations.get(material) && parser.associations.get(material).materials;
          const matDef = matIndex !== undefined ? json.materials[matIndex] : null;
          const matExt = matDef && matDef.extensions && matDef.extensions[EXTENSION];
          if (matExt && matExt.fallbackEmission) {
            m.emissiveMap = null;
            m.emissive.setRGB(...(matExt.emissiveFactor || [0, 0, 0]));
            m.emissiveIntensity = 1.0;
          }
          // three.js's lightMap machinery gives the lightmap UV (channel k, scaleOffset transform);
          // its sampler is the I_z texture, its intensity the unit conversion π.
          const lm = main.uniforms.hhdAIz.value.clone();
          lm.channel = k;
          lm.repeat.set(sx, sy);
          lm.offset.set(ox, oy);
          lm.needsUpdate = true;
          m.lightMap = lm;
          m.lightMapIntensity = root.threeLightMapIntensity || Math.PI;
          const uniforms = {
            ...main.uniforms,
            hhdDebug: controls.uniforms.hhdDebug,
            hhdAtlasIndex: { value: ext.atlas },
          };
          sets.forEach((s, i) => {
            Object.assign(uniforms, s.uniforms);
            uniforms[`hhdSetWeight${i}`] = { value: controls.weights[setIndex[i]] };
          });
          if (sets.length) uniforms.hhdBlendSets = controls.uniforms.hhdBlendSets;
          const spec = {
            layers: [main.glsl],
            sets: sets.map((s) => s.glsl),
            ahd: atlas.model === 'ahd',
            selfBounce: this.options.selfBounce,
            filter: controls.filter,
          };
          patchMaterial(m, receiverGLSL(spec), uniforms, `hhd|${JSON.stringify(spec)}`);
          m.userData.hhdReceiver = { node, atlas: ext.atlas };
          patched.set(key, m);
          return m;
        });
        mesh.material = Array.isArray(mesh.material) ? out : out[0];
        mesh.userData.hhdReceiver = { node, atlas: ext.atlas };
        receiverMeshes.add(mesh);
        controls.receivers.push({ object: mesh, node, atlas: ext.atlas });
      }
    }

    // Probe volumes light every other standard-material mesh.
    const volumes = (root.probeVolumes || []).slice(0, MAX_VOLUMES);
    if (this.options.probes && volumes.length) {
      const uniforms = { hhdDebug: controls.uniforms.hhdDebug };
      for (let i = 0; i < volumes.length; ++i) {
        const v = volumes[i];
        const [nx, ny, nz] = v.resolution;
        const count = nx * ny * nz;
        const sh = await parser.getDependency('accessor', v.sh);
        const src = sh.array;
        // texture: width = min(count, 1024) probes, 9 rows per band of probes, RGBA float
        const width = Math.min(count, 1024);
        const bands = Math.ceil(count / width);
        const data = new Float32Array(width * bands * 9 * 4);
        for (let p = 0; p < count; ++p) {
          const x = p % width;
          const yb = 9 * Math.floor(p / width);
          for (let k = 0; k < 9; ++k) {
            const o = ((yb + k) * width + x) * 4;
            data[o] = src[(p * 9 + k) * 3];
            data[o + 1] = src[(p * 9 + k) * 3 + 1];
            data[o + 2] = src[(p * 9 + k) * 3 + 2];
            data[o + 3] = 1;
          }
        }
        const tex = new DataTexture(data, width, bands * 9, RGBAFormat, FloatType);
        tex.minFilter = NearestFilter;
        tex.magFilter = NearestFilter;
        tex.needsUpdate = true;
        const toWorld = new Matrix4().fromArray(v.matrix);
        uniforms[`hhdProbe${i}`] = { value: tex };
        uniforms[`hhdProbeToLocal${i}`] = { value: toWorld.clone().invert() };
        uniforms[`hhdProbeRes${i}`] = { value: new Vector3(nx, ny, nz) };
      }
      const glsl = probeGLSL(volumes);
      const done = new Map();
      result.scene.traverse((object) => {
        if (!object.isMesh || receiverMeshes.has(object)) return;
        const materials = Array.isArray(object.material) ? object.material : [object.material];
        const out = materials.map((material) => {
          if (!isPatchable(material)) return material;
          if (!done.has(material.uuid)) {
            const m = material.clone();
            patchMaterial(m, glsl, uniforms, `hhdprobes|${volumes.length}`);
            m.userData.hhdProbeLit = true;
            done.set(material.uuid, m);
          }
          return done.get(material.uuid);
        });
        object.material = Array.isArray(object.material) ? out : out[0];
        object.userData.hhdProbeLit = true;
        controls.probeLit.push(object);
      });
    }
    for (const w of controls.warnings) console.warn(`${EXTENSION}: ${w}`);
  }
}
