#version 330
// Insertion compositing (supplement D.2) of every inserted object into one view of the panorama.
// Per view pixel: the objects' impostors (object.frag, one tile each in imp_atlas, looked up by the
// pixel's direction: every camera sits at the panorama's centre), and the scene surface seen there
// as a receiver of the objects' shadows:
//   dE = - sum_lights E_j(x) (1 - V_j(x))                        dominant lights, shadow maps (PCSS)
//        + sum_proxies pi FF_k(x) (L_object(w_k) - L_residual(w_k))   occlusion near contact + bounce
// (L_residual: the object's probe without its lights, averaged over the proxy's cone) and, for the
// specular lobe of glossy receivers, the object replacing what the lobe reflected:
//   dS = (F0 A + B) overlap(lobe, proxies) (L_object - L_probe(r))
// I_all - I_pl = B (1 - M) dE / pi + dS is added to the background (the differential of D.2); the
// object's pixels take its radiance (I_all or I_obj, chosen when object.frag ran).
// VIEWER 0 (export): background from the panorama (scene_image); linear composite, object-only and
// shadow-matte targets.  VIEWER 1 (the viewer's overlay pass): background = the layer exactly as
// viewer/renderer.py samples it (layer.glsl), output in display colours (display.glsl).
#include "scene.glsl"
#include "view.glsl"
#include "occlusion.glsl"
#include "impostors.glsl"
#ifndef VIEWER
#define VIEWER 0
#endif
#if VIEWER
#include "layer.glsl"
#include "display.glsl"
#endif
#ifndef GLOSSY_RECEIVERS
#define GLOSSY_RECEIVERS 1
#endif
// cheaper variants while an object is dragged (viewer.insertion.Quality); software GL runs every
// instruction of a shader for every pixel, so texture look-ups per pixel set the cost
#ifndef PROXY_LOOKUPS
#define PROXY_LOOKUPS 1  // 0: the radiance an object hides looked up once per object, not per proxy
#endif
#ifndef BLOCKER_SEARCH
#define BLOCKER_SEARCH 1  // 0: PCSS without its blocker search: the blocker at the object's bounding sphere
#endif
#ifndef DRAFT
#define DRAFT 0  // 1 (with VIEWER): the receivers' kept share only, at a lower resolution
#endif           // (composite_up.frag puts it and the objects over the full-resolution layer)
#define MAX_LIGHTS 16
#define MAX_PROXIES 64

uniform sampler2D shadow_atlas;       // distance from each light to the object, one tile per light
uniform int has_albedo;

uniform vec4 obj_sphere[MAX_OBJECTS]; // bounding sphere (centre, radius)
uniform float obj_reach[MAX_OBJECTS]; // occlusion fades out toward this distance from the centre
uniform vec3 amb_full[MAX_OBJECTS * 6];  // irradiance / pi of the object's probe around +-x, +-y, +-z
uniform vec3 amb_bounce[MAX_OBJECTS * 6];  // the same on the object's surface: its shadow on the floor
                                         // darkens what its lower side gets (support_shadowed)
uniform sampler2DArray obj_probes;       // layer 2k: object k's probe without its lights, 2k+1: the probe
uniform sampler2D scene_rm;              // receivers' roughness (r) and metalness (g)
uniform sampler2D dfg;                   // (A, B) over (n.v, R), as in ibl.glsl
uniform float residual_texel;            // solid angle of a level-0 texel at the equator
uniform vec3 obj_albedo[MAX_OBJECTS];    // diffuse + specular albedo: what the object reflects

uniform int n_lights;
uniform int light_obj[MAX_LIGHTS];
uniform vec3 light_pos[MAX_LIGHTS];
uniform vec3 light_power[MAX_LIGHTS];    // irradiance at the object's centre facing the light
uniform float light_dist[MAX_LIGHTS];    // from the object's centre
uniform float light_size[MAX_LIGHTS];    // source radius, metres
uniform mat4 light_vp[MAX_LIGHTS];
uniform float light_tan[MAX_LIGHTS];     // tan of the half field of view of its shadow camera
uniform float light_near[MAX_LIGHTS];
uniform vec4 light_tile[MAX_LIGHTS];
uniform float shadow_texel;              // ndc size of one shadow-map texel
uniform int shadow_taps;                 // Poisson taps of the blocker search and of the filter (<= 16)

uniform ivec2 proxy_range[MAX_OBJECTS];  // object k's proxies: proxy[x, y) (a loop over only its own:
                                         // software GL pays every iteration of every pixel)
uniform vec4 proxy[MAX_PROXIES];         // spheres (centre, radius) standing in for each object's volume

#if VIEWER && DRAFT
layout(location = 0) out vec4 out_keep;     // the receiver's kept share of its light (rgb), 1
#else
layout(location = 0) out vec4 out_colour;   // composite (rgb), object alpha (a)
#endif
#if !VIEWER
layout(location = 1) out vec4 out_object;   // object radiance x alpha (rgb), alpha
layout(location = 2) out vec4 out_shadow;   // shadow matte (fraction of light removed), dE / pi, 0, 1
#endif

const vec2 POISSON[16] = vec2[16](
    vec2(-0.94201624, -0.39906216), vec2(0.94558609, -0.76890725), vec2(-0.09418410, -0.92938870),
    vec2(0.34495938, 0.29387760), vec2(-0.91588581, 0.45771432), vec2(-0.81544232, -0.87912464),
    vec2(-0.38277543, 0.27676845), vec2(0.97484398, 0.75648379), vec2(0.44323325, -0.97511554),
    vec2(0.53742981, -0.47373420), vec2(-0.26496911, -0.41893023), vec2(0.79197514, 0.19090188),
    vec2(-0.24188840, 0.99706507), vec2(-0.81409955, 0.91437590), vec2(0.19984126, 0.78641367),
    vec2(0.14383161, -0.14100790));

// half-life 2 ambient cubes: cos^2-weighted blend of the six axis values of object k
vec3 cube_blend(vec3 px, vec3 nx, vec3 py, vec3 ny, vec3 pz, vec3 nz, vec3 d) {
    vec3 w = d * d;
    return w.x * (d.x >= 0.0 ? px : nx) + w.y * (d.y >= 0.0 ? py : ny) + w.z * (d.z >= 0.0 ? pz : nz);
}

vec3 ambient_full(int k, vec3 d) {
    int o = 6 * k;
    return cube_blend(amb_full[o], amb_full[o + 1], amb_full[o + 2], amb_full[o + 3], amb_full[o + 4],
                      amb_full[o + 5], d);
}

vec3 ambient_bounce(int k, vec3 d) {
    int o = 6 * k;
    return cube_blend(amb_bounce[o], amb_bounce[o + 1], amb_bounce[o + 2], amb_bounce[o + 3], amb_bounce[o + 4],
                      amb_bounce[o + 5], d);
}

float shadow_distance(int j, vec2 ndc) {
    vec4 t = light_tile[j];
    vec2 st = t.xy + (clamp(ndc, -1.0, 1.0) * 0.5 + 0.5) * t.zw;
    return texture(shadow_atlas, st).r;
}

// visibility of light j from receiver x: percentage-closer soft shadows
float light_visibility(int j, vec3 x) {
    vec4 c = light_vp[j] * vec4(x, 1.0);
    if (c.w <= 1e-6) return 1.0;
    vec2 ndc = c.xy / c.w;
    if (any(greaterThan(abs(ndc), vec2(1.0)))) return 1.0;
    float dr = length(x - light_pos[j]);
    float bias = 1e-3 * dr + 0.004;
#if BLOCKER_SEARCH
    float near = light_near[j];
    float search = clamp(light_size[j] * max(dr - near, 0.0) / (dr * near * light_tan[j]), shadow_texel, 0.5);
    float blockers = 0.0, count = 0.0;
    for (int i = 0; i < shadow_taps; ++i) {
        float d = shadow_distance(j, ndc + POISSON[i] * search);
        if (d < dr - bias) { blockers += d; count += 1.0; }
    }
    if (count == 0.0) return 1.0;
    float db = blockers / count;
#else
    // the blocker: the object's side facing the light (a sphere's mean depth over its disc: 2/3 r)
    float db = light_dist[j] - 0.667 * obj_sphere[light_obj[j]].w;
#endif
    float penumbra = light_size[j] * (dr - db) / db;
    float radius = max(penumbra / (dr * light_tan[j]), 1.5 * shadow_texel);
    float lit = 0.0;
    for (int i = 0; i < shadow_taps; ++i)
        lit += shadow_distance(j, ndc + POISSON[i] * radius) >= dr - bias ? 1.0 : 0.0;
    return lit / float(shadow_taps);
}

void main() {
    bool inside;
    vec2 uv = view_uv(scene_size, inside);
#if VIEWER
    vec3 bg = layer_value().rgb;
#else
    // explicit gradients: u jumps by a whole turn at the panorama's seam, and implicit derivatives
    // would pick the coarsest mip level along that line (a dotted seam in perspective exports)
    vec2 t = uv / scene_size;
    vec2 tdx = dFdx(t), tdy = dFdy(t);
    tdx.x -= round(tdx.x);
    tdy.x -= round(tdy.x);
    vec3 bg = textureGrad(scene_image, t, tdx, tdy).rgb;
#endif
    vec4 result = vec4(bg, 0.0);
    vec3 obj_rgb = vec3(0.0);
    float alpha = 0.0, matte = 0.0, de_pi = 0.0;
    vec3 keep = vec3(1.0);  // the share of the receiver's light the objects leave
    if (inside) {
        vec3 d = uv_to_dir(uv, scene_size);
#if !DRAFT  // the draft's objects: composite_up.frag, at full resolution
        vec4 seen = objects_seen(d);
        obj_rgb = seen.rgb;
        alpha = seen.a;
#endif
        // -- the scene surface as a receiver
        float depth = scene_depth_at(d);
        if (depth > 0.0) {
            ivec2 ij = scene_texel(d);
            vec3 x = depth * d;
            vec3 n = normalize(texelFetch(scene_normal, ij, 0).xyz);
            vec2 rm = texelFetch(scene_rm, ij, 0).rg;
            vec3 base = texelFetch(scene_albedo, ij, 0).rgb;
            vec3 view = -d;
            vec3 rs = 2.0 * dot(view, n) * n - view;
            float lobe_w = max(2.0 * atan(0.64 * max(rm.r * rm.r, 1e-3)) * 1.5, 0.02);
            vec2 ab = texture(dfg, vec2(clamp(dot(n, view), 0.0, 1.0), rm.r)).rg;
            vec3 spec_albedo = (0.04 * (1.0 - rm.g) + rm.g * base) * ab.x + ab.y;
            vec3 dS = vec3(0.0);
            vec3 s_pl = vec3(0.0);  // what the receiver's specular lobe reflected before (spec_albedo x L)
            vec3 dE = vec3(0.0);
            vec3 e_pl = vec3(0.0);
            float e_lights = 0.0;  // the brightest unshadowed light's irradiance (luminance)
            bool near_any = false;
            for (int k = 0; k < n_objects; ++k) {
                float dc = length(x - obj_sphere[k].xyz);
                if (dc > obj_reach[k]) continue;
                near_any = true;
                e_pl = max(e_pl, PI * ambient_full(k, n));
                // ambient occlusion and bounce from the proxies of object k: the radiance it hides
                // (its probe's residual over each proxy's cone) and what it sends back
                float ff_sum = 0.0, keep = 1.0;
                vec3 acc = vec3(0.0);
#if !PROXY_LOOKUPS
                vec3 hid_dir = vec3(0.0);
                float hid_cone = 0.0;
#endif
                for (int q = proxy_range[k].x; q < proxy_range[k].y; ++q) {
                    vec3 w = proxy[q].xyz - x;
                    float dd = max(dot(w, w), 1e-12);
                    float sin2 = proxy[q].w * proxy[q].w / dd;
                    if (sin2 < 1e-3) continue;  // covers < 0.1% of the hemisphere
                    vec3 wn = w * inversesqrt(dd);
                    float ff = sphere_form_factor(dot(n, wn), sin2);
                    if (ff <= 0.0) continue;
                    float cone = 2.0 * PI * (1.0 - sqrt(max(1.0 - min(sin2, 1.0), 0.0)));
#if PROXY_LOOKUPS
                    float lod = 0.5 * log2(max(cone / residual_texel, 1.0));
                    vec3 hidden = textureLod(obj_probes, vec3(scene_st(wn), float(2 * k)), lod).rgb;
                    acc += ff * (obj_albedo[k] * ambient_bounce(k, -wn) - hidden);
#else
                    acc += ff * obj_albedo[k] * ambient_bounce(k, -wn);
                    hid_dir += ff * wn;
                    hid_cone += ff * cone;
#endif
                    ff_sum += ff;
                    keep *= 1.0 - ff;
                }
#if !PROXY_LOOKUPS
                if (ff_sum > 0.0) {  // one look-up: form-factor-weighted direction and cone of the proxies
                    float lod = 0.5 * log2(max(hid_cone / ff_sum / residual_texel, 1.0));
                    acc -= ff_sum * textureLod(obj_probes, vec3(scene_st(hid_dir), float(2 * k)), lod).rgb;
                }
#endif
                float fade = smoothstep(obj_reach[k], 0.7 * obj_reach[k], dc);  // no edge at the reach
                if (ff_sum > 0.0) dE += acc * (fade * PI * (1.0 - keep) / ff_sum);  // overlaps: 1-prod(1-ff)
#if GLOSSY_RECEIVERS
                // the receiver's specular lobe (around rs, half-width lobe_w) meeting the proxies
                float seen = 1.0, f_sum = 0.0;
                vec3 l_seen = vec3(0.0);
                for (int q = proxy_range[k].x; q < proxy_range[k].y; ++q) {
                    vec3 w = proxy[q].xyz - x;
                    float dist = length(w);
                    float sigma = asin(min(proxy[q].w / dist, 1.0));
                    float delta = acos(clamp(dot(rs, w / dist), -1.0, 1.0));
                    float f = clamp((sigma + lobe_w - delta) / (2.0 * lobe_w), 0.0, 1.0)
                              * min(1.0, sigma * sigma / (lobe_w * lobe_w));
                    if (f <= 0.0) continue;
                    l_seen += f * obj_albedo[k] * ambient_bounce(k, -w / dist);
                    f_sum += f;
                    seen *= 1.0 - f;
                }
                if (seen < 1.0) {
                    float lod = 0.5 * log2(max(PI * lobe_w * lobe_w / residual_texel, 1.0));
                    vec3 l_env = textureLod(obj_probes, vec3(scene_st(rs), float(2 * k + 1)), lod).rgb;
                    dS += fade * spec_albedo * (1.0 - seen) * (l_seen / f_sum - l_env);
                    s_pl = max(s_pl, spec_albedo * l_env);
                }
#endif
            }
            for (int j = 0; j < n_lights; ++j) {
                int k = light_obj[j];
                vec3 to_l = light_pos[j] - x;
                float dl = length(to_l);
                float cos_l = dot(n, to_l / max(dl, 1e-6));
                if (cos_l <= 0.0) continue;
                vec4 c = light_vp[j] * vec4(x, 1.0);
                if (c.w <= 1e-6 || any(greaterThan(abs(c.xy / c.w), vec2(1.0)))) continue;
                float fall = light_dist[j] * light_dist[j] / max(dl * dl, 1e-6);
                vec3 e = light_power[j] * min(fall, 16.0) * cos_l;
                e_lights = max(e_lights, dot(e, vec3(0.2126, 0.7152, 0.0722)));
                e_pl = max(e_pl, PI * ambient_full(k, n));
                dE -= e * (1.0 - light_visibility(j, x));
                near_any = true;
            }
            if (near_any) {
                // The photo already holds albedo x irradiance: the receiver keeps the share of its
                // irradiance the objects leave (bg x (E + dE) / E).  The additive form of D.2,
                // bg + albedo dE / pi with the predicted albedo and lighting, went negative (a black,
                // coloured halo) wherever those over-estimated what the photo shows.
                vec3 e_ref = max(e_pl, vec3(e_lights));
                vec3 keep_share = max(vec3(1.0) + dE / max(e_ref, vec3(1e-6)), vec3(0.0));
                // the specular change in the same ratio form: the share of the photo the lobe
                // reflected (predicted specular / predicted total) changes by dS / s_pl; added as
                // bg + dS it went black wherever the predicted reflection (a lamp) outshone the photo
                vec3 d_pl = base * (1.0 - rm.g) * e_ref / PI;
                vec3 f_spec = has_albedo == 0 ? vec3(0.0) : s_pl / max(d_pl + s_pl, vec3(1e-6));
                vec3 spec_keep = max(vec3(1.0) + dS / max(s_pl, vec3(1e-6)), vec3(0.0));
                keep_share = (1.0 - f_spec) * keep_share + f_spec * spec_keep;
                vec3 shadowed = bg * keep_share;
                float lum_pl = dot(e_ref, vec3(0.2126, 0.7152, 0.0722));
                matte = clamp(-dot(dE, vec3(0.2126, 0.7152, 0.0722)) / max(lum_pl, 1e-6), 0.0, 1.0);
                de_pi = dot(shadowed - bg, vec3(0.2126, 0.7152, 0.0722));
                result.rgb = shadowed;
                keep = keep_share;
            }
        }
        result.rgb = obj_rgb + (1.0 - alpha) * result.rgb;
        result.a = alpha;
    }
#if VIEWER && DRAFT
    out_keep = vec4(keep, 1.0);
#elif VIEWER
    out_colour = display_colour(vec4(result.rgb, inside ? 1.0 : 0.0));
#else
    out_colour = result;
    out_object = vec4(obj_rgb, alpha);
    out_shadow = vec4(matte, de_pi, 0.0, 1.0);
#endif
}
