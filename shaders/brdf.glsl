// The UE4 microfacet BRDF with metalness (supplement A.3): a line-by-line mirror of phyir/brdf.py,
// tested against it (and against phyir.render) in tests/test_insert_gl.py.
//   f = f_d + f_s,  f_d = B (1 - M) / pi,  f_s = D F G / (4 (n.v)(n.l))
//   D = GGX with alpha = R^2;  F = F0 + (1 - F0) 2^((-5.55473 v.h - 6.98316) v.h),  F0 = 0.04 (1 - M) + M B
//   G / (4 n.v n.l) = 1 / (4 ((n.l)(1-k)+k) ((n.v)(1-k)+k)),  k = (R + 1)^2 / 8.
#include "pano.glsl"

const float ALPHA_MIN = 1e-3;  // R = 0 becomes a very sharp lobe, not a delta
const float DIELECTRIC_F0 = 0.04;

float alpha_from_roughness(float roughness) {
    return max(roughness * roughness, ALPHA_MIN);
}

vec3 f0_from_material(vec3 base_color, float metallic) {
    return DIELECTRIC_F0 * (1.0 - metallic) + metallic * base_color;
}

// denominator (1 - c)(1 + c) + c^2 a^2, not c^2 (a^2 - 1) + 1, which cancels near the peak in float32
float ggx_d(float n_dot_h, float alpha) {
    float a2 = alpha * alpha;
    float c = clamp(n_dot_h, 0.0, 1.0);
    float t = (1.0 - c) * (1.0 + c) + c * c * a2;
    return a2 / (PI * t * t);
}

vec3 fresnel_ue4(float v_dot_h, vec3 f0) {
    float c = clamp(v_dot_h, 0.0, 1.0);
    return f0 + (1.0 - f0) * exp2((-5.55473 * c - 6.98316) * c);
}

float schlick_k(float roughness) {
    return (roughness + 1.0) * (roughness + 1.0) / 8.0;
}

float g1_schlick(float n_dot_x, float k) {
    float c = clamp(n_dot_x, 0.0, 1.0);
    return c / (c * (1.0 - k) + k);
}

// G / (4 (n.v)(n.l)) in its finite form
float visibility(float n_dot_l, float n_dot_v, float roughness) {
    float k = schlick_k(roughness);
    float nl = clamp(n_dot_l, 0.0, 1.0);
    float nv = clamp(n_dot_v, 0.0, 1.0);
    return 1.0 / (4.0 * (nl * (1.0 - k) + k) * (nv * (1.0 - k) + k));
}

vec3 brdf_diffuse(vec3 base_color, float metallic) {
    return base_color * (1.0 - metallic) / PI;
}

// zero where the light or the eye is below the surface
vec3 brdf_specular(float n_dot_l, float n_dot_v, float n_dot_h, float v_dot_h,
                   vec3 base_color, float roughness, float metallic) {
    float alpha = alpha_from_roughness(roughness);
    vec3 f = ggx_d(n_dot_h, alpha) * fresnel_ue4(v_dot_h, f0_from_material(base_color, metallic))
             * visibility(n_dot_l, n_dot_v, roughness);
    return (n_dot_l > 0.0 && n_dot_v > 0.0) ? f : vec3(0.0);
}

// (f_d, f_s) for the given cosines; f_d is zero where n.l <= 0 or n.v <= 0
void brdf(float n_dot_l, float n_dot_v, float n_dot_h, float v_dot_h, vec3 base_color, float roughness,
          float metallic, out vec3 fd, out vec3 fs) {
    fs = brdf_specular(n_dot_l, n_dot_v, n_dot_h, v_dot_h, base_color, roughness, metallic);
    fd = (n_dot_l > 0.0 && n_dot_v > 0.0) ? brdf_diffuse(base_color, metallic) : vec3(0.0);
}

// (n.l, n.v, n.h, v.h) of unit vectors
vec4 cosines(vec3 n, vec3 v, vec3 l) {
    vec3 h = v + l;
    h = h / max(length(h), 1e-12);
    return vec4(dot(n, l), dot(n, v), dot(n, h), dot(v, h));
}

void brdf_vectors(vec3 n, vec3 v, vec3 l, vec3 base_color, float roughness, float metallic,
                  out vec3 fd, out vec3 fs) {
    vec4 c = cosines(n, v, l);
    brdf(c.x, c.y, c.z, c.w, base_color, roughness, metallic, fd, fs);
}
