// Image-based lighting of an inserted object from its own light probe (docs/insertion.md).
//   diffuse  = B (1 - M) I(n): I = irradiance / pi of the probe, an exact quadrature map (env_irr)
//   specular = the probe's brightest texels as point samples (peak_dir/peak_power, see
//              phyir.object_lighting.peak_samples), plus filtered importance sampling of the rest
//              (env_spec): spec_samples GGX directions from a Hammersley set, each weighted by
//              F G 4 (v.h)(n.l) / (n.h) (f_s cos / pdf) and looked up in its mip pyramid at the
//              level of the sample's solid angle 1 / (N pdf)
//   mirror   = (R < mirror_roughness, as phyir.render's "mirror" skip) one look-up in the reflected
//              direction times the lobe's directional albedo F0 A + B from the DFG table
// The radiance a direction brings is incoming(); the including shader defines it (the probe, the
// depth panorama, the virtual plane).
#include "sampling.glsl"

#define MAX_PEAKS 32
uniform sampler2D env;          // the object's probe, equirect (mirror look-ups)
uniform sampler2D env_spec;     // the probe without its peak samples, mips = area-downsampled levels
uniform sampler2D env_irr;      // irradiance / pi per normal direction, equirect
uniform int n_peaks;
uniform vec3 peak_dir[MAX_PEAKS];
uniform vec3 peak_power[MAX_PEAKS];  // radiance x solid angle
uniform sampler2D dfg;          // (A, B) over (n.v [s], R [t]) at texel centres, clamp to edge
uniform vec2 env_size;          // (w, h) of the probe's level 0
uniform float env_max_lod;
uniform int spec_samples;
uniform float mirror_roughness;
uniform float lod_bias;

// texture coordinates (s, t) of a direction in an equirect texture (dir_to_uv of a 1 x 1 image)
vec2 dir_st(vec3 d) {
    return dir_to_uv(d, vec2(1.0));
}

vec3 env_lod(vec3 d, float lod) {
    return textureLod(env_spec, dir_st(d), clamp(lod, 0.0, env_max_lod)).rgb;
}

vec3 env_sharp(vec3 d) {
    return textureLod(env, dir_st(d), 0.0).rgb;
}

// prefilter.specular_albedo: F0 A + B
vec3 specular_albedo(float n_dot_v, float roughness, vec3 f0) {
    vec2 ab = texture(dfg, vec2(n_dot_v, roughness)).rg;
    return f0 * ab.x + ab.y;
}

vec3 diffuse_ibl(vec3 n, vec3 base_color, float metallic) {
    return base_color * (1.0 - metallic) * texture(env_irr, dir_st(n)).rgb;
}

// level of the probe's mip pyramid whose texels cover the solid angle 1 / (N pdf) of one sample
float sample_lod(vec3 l, float pdf, int n) {
    float texel = 2.0 * PI * PI / (env_size.x * env_size.y) * max(length(l.xz), 1.0 / env_size.y);
    return 0.5 * log2(1.0 / (float(n) * max(pdf, 1e-12) * texel)) + lod_bias;
}

vec3 incoming(vec3 p, vec3 l, float lod);
vec3 incoming_sharp(vec3 p, vec3 l);

vec3 specular_ibl(vec3 p, vec3 n, vec3 v, vec3 base_color, float roughness, float metallic) {
    float nv = dot(n, v);
    vec3 f0 = f0_from_material(base_color, metallic);
    if (roughness < mirror_roughness)
        return incoming_sharp(p, reflect_about(v, n)) * specular_albedo(nv, roughness, f0);
    float alpha = alpha_from_roughness(roughness);
    int count = max(spec_samples, 1);
    vec3 peaks = vec3(0.0);
    for (int i = 0; i < n_peaks; ++i) {
        vec3 l = peak_dir[i];
        vec4 c = cosines(n, v, l);
        if (c.x <= 0.0) continue;
        peaks += brdf_specular(c.x, c.y, c.z, c.w, base_color, roughness, metallic) * (c.x * peak_power[i]);
    }
    vec3 sum = vec3(0.0);
    for (int i = 0; i < count; ++i) {
        vec3 h = local_to_world(ggx_half_vector(hammersley(i, count), alpha), n);
        vec3 l = reflect_about(v, h);
        float nl = dot(n, l), nh = dot(n, h), vh = dot(v, h);
        if (nl <= 0.0 || vh <= 0.0) continue;
        vec3 w = fresnel_ue4(vh, f0) * (visibility(nl, nv, roughness) * 4.0 * vh * nl / max(nh, 1e-12));
        sum += w * incoming(p, l, sample_lod(l, ggx_pdf(nh, vh, alpha), count));
    }
    return peaks + sum / float(count);
}

// outgoing radiance toward v of the surface at p with unit normal n (n.v > 0)
vec3 shade_ibl(vec3 p, vec3 n, vec3 v, vec3 base_color, float roughness, float metallic) {
    return diffuse_ibl(n, base_color, metallic) + specular_ibl(p, n, v, base_color, roughness, metallic);
}
