// The inserted objects seen in direction d: their impostor tiles (object.frag, one per object in
// imp_atlas; every camera sits at the panorama's centre, so a direction finds each object's pixel).
// composite.frag reads them with the receivers; composite_up.frag at full resolution over the draft.
#define MAX_OBJECTS 8

uniform sampler2D imp_atlas;          // object radiance (rgb) and visibility (a), one tile per object
uniform int n_objects;
uniform mat4 imp_vp[MAX_OBJECTS];     // world -> clip of each object's impostor camera
uniform vec4 imp_tile[MAX_OBJECTS];   // (s0, t0, ds, dt) of its tile in imp_atlas

// premultiplied radiance (rgb) and coverage (a) of the objects, sorted far to near by the caller
vec4 objects_seen(vec3 d) {
    vec3 obj_rgb = vec3(0.0);
    float alpha = 0.0;
    for (int k = 0; k < n_objects; ++k) {
        vec4 c = imp_vp[k] * vec4(d, 1.0);
        if (c.w <= 1e-6) continue;
        vec2 ndc = c.xy / c.w;
        if (any(greaterThan(abs(ndc), vec2(1.0)))) continue;
        vec4 t = imp_tile[k];
        vec4 s = texture(imp_atlas, t.xy + (ndc * 0.5 + 0.5) * t.zw);
        obj_rgb = s.rgb + (1.0 - s.a) * obj_rgb;
        alpha = s.a + (1.0 - s.a) * alpha;
    }
    return vec4(obj_rgb, alpha);
}
