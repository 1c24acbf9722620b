// The panorama's layers as the insertion shaders see them, and projection-based lighting on the
// GPU: a line-by-line mirror of phyir.projection.DepthSurface.trace (march the radial depth, bisect,
// reject crossings on depth discontinuities), reading radiance from the panorama at the hit.
#include "pano.glsl"

uniform sampler2D scene_depth;   // full-resolution radial depth (metres), fetched texel by texel
uniform sampler2D scene_normal;
uniform sampler2D scene_albedo;
uniform sampler2D scene_image;   // radiance with mip levels (footprint-filtered look-ups)
uniform sampler2D march_depth;   // DepthSurface.depth_tex: radial depth at the marching resolution
uniform sampler2D march_jump;    // DepthSurface.jump_tex: relative depth jump of each bilinear cell
uniform vec2 scene_size;         // (W, H) of the panorama
uniform float r_bound;           // every point of the depth surface is within this radius
uniform float jump_threshold;
uniform int march_steps;

vec2 scene_st(vec3 d) {
    return dir_to_uv(d, vec2(1.0));
}

ivec2 wrap_texel(ivec2 ij, ivec2 size) {
    return ivec2(((ij.x % size.x) + size.x) % size.x, clamp(ij.y, 0, size.y - 1));
}

// the panorama pixel seen in direction d (no interpolation across depth edges)
ivec2 scene_texel(vec3 d) {
    ivec2 ts = textureSize(scene_depth, 0);
    return wrap_texel(ivec2(floor(scene_st(d) * vec2(ts))), ts);
}

float scene_depth_at(vec3 d) {
    return texelFetch(scene_depth, scene_texel(d), 0).r;
}

// |p| - D(direction of p): negative in the camera's free space
float depth_gap(vec3 p) {
    return length(p) - texture(march_depth, scene_st(p)).r;
}

// first crossing of o + t d (unit d) with the depth surface; false where none was found, the ray
// starts outside the free space, or the crossing lies on a depth discontinuity (unseen space)
bool march(vec3 o, vec3 d, out float t_hit) {
    t_hit = 0.0;
    float b = dot(o, d);
    float c = dot(o, o) - r_bound * r_bound;
    float t_exit = -b + sqrt(max(b * b - c, 0.0));
    if (depth_gap(o) >= 0.0) return false;
    float lo = 0.0, hi = 0.0;
    bool found = false;
    float steps = float(march_steps);
    for (int k = 1; k <= march_steps; ++k) {
        float t = t_exit * pow(float(k) / steps, 1.5);
        if (depth_gap(o + t * d) >= 0.0) {
            lo = t_exit * pow(float(k - 1) / steps, 1.5);
            hi = t;
            found = true;
            break;
        }
    }
    if (!found) return false;
    for (int i = 0; i < 7; ++i) {
        float mid = 0.5 * (lo + hi);
        if (depth_gap(o + mid * d) >= 0.0) hi = mid; else lo = mid;
    }
    t_hit = 0.5 * (lo + hi);
    ivec2 ms = textureSize(march_jump, 0);
    vec2 uv = scene_st(o + t_hit * d) * vec2(ms);
    float jump = texelFetch(march_jump, wrap_texel(ivec2(floor(uv - 0.5)), ms), 0).r;
    return jump <= jump_threshold;
}

// panorama radiance at surface point x, area-averaged over a footprint of `footprint` steradians
// (as the camera sees it): phyir.projection.DepthSurface.radiance
vec3 scene_radiance(vec3 x, float footprint) {
    float lat = asin(clamp(normalize(x).y, -1.0, 1.0));
    float pix = (2.0 * PI / scene_size.x) * (PI / scene_size.y) * max(cos(lat), 1.0 / scene_size.y);
    float lod = max(0.5 * log2(max(footprint, 1e-30) / pix), 0.0);
    return textureLod(scene_image, scene_st(x), lod).rgb;
}
