#version 330
// Inserted object seen from the panorama's camera (at the origin): shaded by its own probe
// (ibl.glsl), sharp reflections corrected for parallax against the depth panorama (scene.glsl),
// and hidden where the scene is nearer (alpha = 0).  FUSION_PLANE (D.2's differential fusion):
// directions toward the supporting plane see the virtual plane (predicted albedo x its irradiance)
// instead of the probe.  Either way the surface the object rests on is darkened where the object
// itself occludes it (its proxy spheres), so its reflections show its own contact shadow.
#include "ibl.glsl"
#include "scene.glsl"
#include "occlusion.glsl"
#define MAX_OWN_PROXIES 16
#ifndef FUSION_PLANE
#define FUSION_PLANE 0
#endif
#ifndef SHARP
#define SHARP 1  // 0: roughness >= mirror_roughness, ibl.glsl never reflects sharply (no marching compiled)
#endif

in vec3 world_pos;
in vec3 world_normal;
uniform vec3 base_color;
uniform float roughness;
uniform float metallic;
uniform int use_projection;    // 1: mirror reflections from the depth panorama, probe where unseen
uniform float occlusion_eps;   // relative depth margin of the scene-occludes-object test
uniform float footprint_scale; // 1: reflections filtered over the pixel's cone; 0: point-sampled
uniform vec3 plane_point;      // FUSION_PLANE: the surface the object rests on
uniform vec3 plane_normal;
uniform int n_own_proxies;
uniform vec4 own_proxies[MAX_OWN_PROXIES];  // this object's proxy spheres (world)
out vec4 out_colour;

float sharp_spread;            // angular size (radians) of this pixel's reflected cone
float plane_keep;              // own_shadow where the reflected ray meets the plane (all lobe samples)

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

// the share of light the object leaves to surface point x (normal n): 1 - its proxies' coverage
float own_shadow(vec3 x, vec3 n) {
    float keep = 1.0;
    for (int q = 0; q < n_own_proxies; ++q) {
        vec3 w = own_proxies[q].xyz - x;
        float dd = max(dot(w, w), 1e-12);
        float sin2 = own_proxies[q].w * own_proxies[q].w / dd;
        if (sin2 < 1e-3) continue;
        keep *= 1.0 - sphere_form_factor(dot(n, w) * inversesqrt(dd), sin2);
    }
    return keep;
}

vec3 incoming(vec3 p, vec3 l, float lod) {
    vec3 x;
    bool on_plane = plane_hit(p, l, x);
#if FUSION_PLANE
    if (on_plane) return plane_radiance(x) * plane_keep;
#endif
    vec3 c = env_lod(l, lod);
    return on_plane ? c * plane_keep : c;
}

vec3 incoming_sharp(vec3 p, vec3 l) {
#if !SHARP
    return vec3(0.0);  // never called (software GL would still run the march for every pixel)
#endif
    vec3 x;
    bool on_plane = plane_hit(p, l, x);
#if FUSION_PLANE
    if (on_plane) return plane_radiance(x) * own_shadow(x, plane_normal);
#endif
    if (use_projection != 0) {
        float t;
        if (march(p, l, t)) {
            vec3 y = p + t * l;
            float r = max(length(y), 1e-6);
            vec3 c = scene_radiance(y, sharp_spread * sharp_spread * (t / r) * (t / r));
            vec3 ny = normalize(texelFetch(scene_normal, scene_texel(y), 0).xyz);
            return c * own_shadow(y, ny);
        }
    }
    vec3 c = env_sharp(l);
    return on_plane ? c * own_shadow(x, plane_normal) : c;
}

void main() {
    vec3 p = world_pos;
    vec3 v = normalize(-p);
    vec3 n = normalize(world_normal);
    if (!gl_FrontFacing) n = -n;  // open meshes: the back side faces the camera
    float nv = dot(n, v);
    if (nv < 1e-4) n = normalize(n + v * (1e-4 - nv));  // interpolated normals at silhouettes
    vec3 r = reflect_about(v, n);
    sharp_spread = footprint_scale * max(length(dFdx(r)), length(dFdy(r)));
    // the object's shadow on its plane, evaluated once: where the reflected ray (or, for rays
    // going up, the point below) meets it
    vec3 xr;
    if (!plane_hit(p, r, xr)) xr = p - dot(p - plane_point, plane_normal) * plane_normal;
    plane_keep = own_shadow(xr, plane_normal);
    float visible = length(p) <= scene_depth_at(p) * (1.0 + occlusion_eps) ? 1.0 : 0.0;
    out_colour = vec4(shade_ibl(p, n, v, base_color, roughness, metallic), visible);
}
