// GLSL ES 3.0 ports of docs/format.md's HLSL listings: the HHD reconstruction ("Reconstruction
// (HLSL-like)"), the light-set blend through linear SH ("Runtime blend (HLSL-like)") and the probe
// volumes' L2 SH irradiance. All vectors are in one world frame (the plugin works in three.js's
// world, Y up; the SH blend is covariant under rotation, so the frame does not matter to it).
// Irradiance is the project's unit (albedo × I = outgoing radiance, docs/conventions.md); three.js's
// `irradiance` is π times that, which the plugin applies where it hands the result to three.js.

export const HHD_COMMON = /* glsl */ `
#ifndef HHD_COMMON
#define HHD_COMMON
const vec3 HHD_LUM = vec3(0.2126, 0.7152, 0.0722);   // Rec.709 luminance
const float HHD_MIN_COS = 0.02;                       // the encoder's floor on d·nv
const float HHD_SQRT_PI = 1.7724539;
const float HHD_SQRT3 = 1.7320508;

struct HHDTexel { vec3 Iz; vec3 wa; vec3 d; };        // wa: luminance mode has wa.r = wa.g = wa.b
struct HHDLinearSH { vec3 l0; vec3 l1m1; vec3 l10; vec3 l11; };

vec3 hhdOctDecode(vec2 e) {                           // inverse of the encoder's octahedral map
  vec3 d = vec3(e.xy, 1.0 - abs(e.x) - abs(e.y));
  float t = clamp(-d.z, 0.0, 1.0);
  d.xy -= t * vec2(d.x >= 0.0 ? 1.0 : -1.0, d.y >= 0.0 ? 1.0 : -1.0);
  return normalize(d);
}

// I(n) = Iz [wa (1 + n·nv)/2 + (1 - wa) max(n·d, 0) / max(d·nv, 0.01)]   (AHD: wa instead of wa (1 + n·nv)/2)
vec3 hhdIrradiance(HHDTexel h, vec3 nv, vec3 n, bool ahd) {
  float dnv = max(dot(h.d, nv), 0.5 * HHD_MIN_COS);
  float ambient = ahd ? 1.0 : 0.5 * (1.0 + dot(n, nv));
  return h.Iz * (h.wa * ambient + (1.0 - h.wa) * (max(dot(n, h.d), 0.0) / dnv));
}

HHDLinearSH hhdToLinearSH(HHDTexel h, vec3 nv) {      // sqrt(pi)/2 [2Ca + Cd, -sqrt3 b.y, sqrt3 b.z, -sqrt3 b.x]
  float dz = max(dot(h.d, nv), 0.5 * HHD_MIN_COS);
  vec3 Ca = h.wa * h.Iz;
  vec3 Cd = (1.0 - h.wa) * h.Iz / dz;
  float k = 0.5 * HHD_SQRT_PI;
  HHDLinearSH s;
  s.l0 = k * (2.0 * Ca + Cd);
  s.l1m1 = -k * HHD_SQRT3 * (Ca * nv.y + Cd * h.d.y);
  s.l10 = k * HHD_SQRT3 * (Ca * nv.z + Cd * h.d.z);
  s.l11 = -k * HHD_SQRT3 * (Ca * nv.x + Cd * h.d.x);
  return s;
}

vec3 hhdTangentOf(vec3 n) {                           // any unit vector perpendicular to n (Duff et al. 2017)
  float s = n.z >= 0.0 ? 1.0 : -1.0;
  float a = -1.0 / (s + n.z);
  return vec3(1.0 + s * n.x * n.x * a, s * n.x * n.y * a, -s * n.x);
}

HHDTexel hhdFromLinearSH(HHDLinearSH s, vec3 nv) {    // the talk's closed form, solved on the luminance
  float kb = 2.0 / HHD_SQRT_PI;
  vec3 bc = kb * s.l0;
  vec3 bx = -kb / HHD_SQRT3 * s.l11, by = -kb / HHD_SQRT3 * s.l1m1, bz = kb / HHD_SQRT3 * s.l10;
  HHDTexel h;
  h.Iz = max(bx * nv.x + by * nv.y + bz * nv.z, 0.0);
  float bcL = dot(bc, HHD_LUM), IzL = dot(h.Iz, HHD_LUM);
  vec3 bL = vec3(dot(bx, HHD_LUM), dot(by, HHD_LUM), dot(bz, HHD_LUM));
  float p = 2.0 * bcL - IzL;
  float disc = max(p * p - 3.0 * (bcL * bcL - dot(bL, bL)), 0.0);
  float Ca = clamp((p - sqrt(disc)) / 3.0, 0.0, IzL);
  vec3 dv = bL - Ca * nv;
  float len = length(dv);
  vec3 d = len > 1e-12 * IzL ? dv / len : nv;
  float c = dot(d, nv);
  if (c < HHD_MIN_COS) {                              // tilt up to the cone, keeping the azimuth
    vec3 t = d - c * nv;
    float tl = length(t);
    t = tl > 1e-12 ? t / tl : hhdTangentOf(nv);
    d = HHD_MIN_COS * nv + sqrt(1.0 - HHD_MIN_COS * HHD_MIN_COS) * t;
  }
  h.d = d;
  h.wa = vec3(IzL > 0.0 ? clamp(Ca / IzL, 0.0, 1.0) : 1.0);
  return h;
}

void hhdAccumulate(inout HHDLinearSH sum, HHDTexel h, vec3 nv, vec3 w) {
  HHDLinearSH s = hhdToLinearSH(h, nv);
  sum.l0 += w * s.l0;
  sum.l1m1 += w * s.l1m1;
  sum.l10 += w * s.l10;
  sum.l11 += w * s.l11;
}

// L2 irradiance of world-space radiance SH (conventions.md: bands × 1, 2/3, 1/4, Condon–Shortley
// basis) at the unit normal n, in the Blender frame of the SH (the caller converts n).
vec3 hhdSHIrradiance(vec3 sh[9], vec3 n) {
  float x = n.x, y = n.y, z = n.z;
  vec3 r = 0.282095 * sh[0];
  r += (2.0 / 3.0) * 0.488603 * (-y * sh[1] + z * sh[2] - x * sh[3]);
  r += 0.25 * (1.092548 * x * y * sh[4] - 1.092548 * y * z * sh[5] + 0.315392 * (3.0 * z * z - 1.0) * sh[6]
               - 1.092548 * x * z * sh[7] + 0.546274 * (x * x - y * y) * sh[8]);
  return r;
}
#endif
`;

/** The light-set blend of K sets' texels, GLSL: `HHDTexel hhdBlend(HHDTexel sets[K], vec3 w[K], vec3 nv)`. */
export function blendGLSL(k) {
  return /* glsl */ `
HHDTexel hhdBlend${k}(HHDTexel sets[${k}], vec3 w[${k}], vec3 nv) {
  HHDLinearSH sum = HHDLinearSH(vec3(0.0), vec3(0.0), vec3(0.0), vec3(0.0));
  for (int i = 0; i < ${k}; ++i) hhdAccumulate(sum, sets[i], nv, w[i]);
  return hhdFromLinearSH(sum, nv);
}
`;
}
