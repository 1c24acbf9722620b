#version 330
// Inserted object seen from the panorama's camera (at the origin): shaded by its own probe
// (ibl.glsl), sharp reflections corrected for parallax against the depth panorama (scene.glsl),
// and hidden where the scene is nearer (alpha = 0).  FUSION_PLANE (D.2's differential fusion):
// directions toward the supporting plane see the virtual plane (predicted albedo x its irradiance)
// instead of the probe.
#include "ibl.glsl"
#include "scene.glsl"
#ifndef FUSION_PLANE
#define FUSION_PLANE 0
#endif

in vec3 world_pos;
in vec3 world_normal;
uniform vec3 base_color;
uniform float roughness;
uniform float metallic;
uniform int use_projection;    // 1: mirror reflections from the depth panorama, probe where unseen
uniform float occlusion_eps;   // relative depth margin of the scene-occludes-object test
uniform vec3 plane_point;      // FUSION_PLANE: the surface the object rests on
uniform vec3 plane_normal;
out vec4 out_colour;

float sharp_spread;            // angular size (radians) of this pixel's reflected cone

bool plane_hit(vec3 p, vec3 l, out vec3 x) {
    x = p;
    float den = dot(l, plane_normal);
    if (den >= -1e-4) return false;
    float t = dot(plane_point - p, plane_normal) / den;
    if (t <= 0.0) return false;
    x = p + t * l;
    return length(x) <= scene_depth_at(x) * 1.02 + 0.02;  // the plane only where the camera saw free space
}

vec3 plane_radiance(vec3 x) {
    return texture(scene_albedo, scene_st(x)).rgb * texture(env_irr, dir_st(plane_normal)).rgb;
}

vec3 incoming(vec3 p, vec3 l, float lod) {
#if FUSION_PLANE
    vec3 x;
    if (plane_hit(p, l, x)) return plane_radiance(x);
#endif
    return env_lod(l, lod);
}

vec3 incoming_sharp(vec3 p, vec3 l) {
#if FUSION_PLANE
    vec3 x;
    if (plane_hit(p, l, x)) return plane_radiance(x);
#endif
    if (use_projection != 0) {
        float t;
        if (march(p, l, t)) {
            vec3 x = p + t * l;
            float r = max(length(x), 1e-6);
            return scene_radiance(x, sharp_spread * sharp_spread * (t / r) * (t / r));
        }
    }
    return env_sharp(l);
}

void main() {
    vec3 p = world_pos;
    vec3 v = normalize(-p);
    vec3 n = normalize(world_normal);
    if (!gl_FrontFacing) n = -n;  // open meshes: the back side faces the camera
    float nv = dot(n, v);
    if (nv < 1e-4) n = normalize(n + v * (1e-4 - nv));  // interpolated normals at silhouettes
    vec3 r = reflect_about(v, n);
    sharp_spread = max(length(dFdx(r)), length(dFdy(r)));
    float visible = length(p) <= scene_depth_at(p) * (1.0 + occlusion_eps) ? 1.0 : 0.0;
    out_colour = vec4(shade_ibl(p, n, v, base_color, roughness, metallic), visible);
}
