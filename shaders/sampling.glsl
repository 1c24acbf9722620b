// Sampling helpers: a mirror of the parts of phyir/sampling.py the object shader uses
// (Hammersley points, Duff et al.'s frame, GGX half vectors and their pdf).
#include "brdf.glsl"

// Van der Corput radical inverse in base 2 (bit reversal; GLSL 3.30 has no bitfieldReverse)
float radical_inverse_2(uint i) {
    i = (i << 16u) | (i >> 16u);
    i = ((i & 0x55555555u) << 1u) | ((i & 0xAAAAAAAAu) >> 1u);
    i = ((i & 0x33333333u) << 2u) | ((i & 0xCCCCCCCCu) >> 2u);
    i = ((i & 0x0F0F0F0Fu) << 4u) | ((i & 0xF0F0F0F0u) >> 4u);
    i = ((i & 0x00FF00FFu) << 8u) | ((i & 0xFF00FF00u) >> 8u);
    return float(i) * 2.3283064365386963e-10;
}

// sampling.hammersley: ((i + 0.5) / n, phi_2(i))
vec2 hammersley(int i, int n) {
    return vec2((float(i) + 0.5) / float(n), radical_inverse_2(uint(i)));
}

// sampling.orthonormal_basis: tangent t and bitangent b with (t, b, n) right-handed
void orthonormal_basis(vec3 n, out vec3 t, out vec3 b) {
    float sign_ = n.z >= 0.0 ? 1.0 : -1.0;
    float a = -1.0 / (sign_ + n.z);
    float c = n.x * n.y * a;
    t = vec3(1.0 + sign_ * n.x * n.x * a, sign_ * c, -sign_ * n.x);
    b = vec3(c, sign_ + n.y * n.y * a, -n.y);
}

vec3 local_to_world(vec3 local, vec3 n) {
    vec3 t, b;
    orthonormal_basis(n, t, b);
    return local.x * t + local.y * b + local.z * n;
}

// sampling.reflect: mirror v about h (both unit, pointing away from the surface)
vec3 reflect_about(vec3 v, vec3 h) {
    return 2.0 * dot(v, h) * h - v;
}

// sampling.ggx_half_vector (local frame): tan^2 theta = alpha^2 u1 / (1 - u1)
vec3 ggx_half_vector(vec2 u, float alpha) {
    float tan2 = alpha * alpha * u.x / max(1.0 - u.x, 5.960464477539063e-08);
    float cos_t = inversesqrt(1.0 + tan2);
    float sin_t = sqrt(tan2) * cos_t;
    float phi = 2.0 * PI * u.y;
    return vec3(sin_t * cos(phi), sin_t * sin(phi), cos_t);
}

// sampling.ggx_pdf: density of l = reflect(v, h), D(h) (n.h) / (4 (v.h))
float ggx_pdf(float n_dot_h, float v_dot_h, float alpha) {
    return v_dot_h > 0.0 ? ggx_d(n_dot_h, alpha) * max(n_dot_h, 0.0) / (4.0 * max(v_dot_h, 1e-12)) : 0.0;
}
