// Look-up of the selected layer at the panorama coordinates seen by this fragment.
// NEAREST (compile time): 1 = nearest-neighbour look-up (zoomed in), 0 = bilinear.
#include "pano.glsl"
#include "view.glsl"
#ifndef NEAREST
#define NEAREST 0
#endif

uniform sampler2D layer;      // wraps in s (longitude), clamps in t (poles)
uniform vec2 pano_size;       // (W, H) the layer is laid over (the probe atlas is stretched onto it)

// rgb = the linear value of the equirect texture `tex` at panorama coordinates `uv` (view_uv's),
// a = 1 where the view shows the panorama (`inside`; any texture size: it is laid over pano_size,
// so a reference of another size lines up)
vec4 layer_lookup_at(sampler2D tex, vec2 uv, bool inside) {
    if (!inside) return vec4(0.0);
    vec2 st = uv / pano_size;
#if NEAREST
    ivec2 ts = textureSize(tex, 0);
    ivec2 ij = ivec2(floor(st * vec2(ts)));
    ij.x = ((ij.x % ts.x) + ts.x) % ts.x;
    ij.y = clamp(ij.y, 0, ts.y - 1);
    return vec4(texelFetch(tex, ij, 0).rgb, 1.0);
#else
    return vec4(texture(tex, st).rgb, 1.0);
#endif
}

// the same, seen by this fragment
vec4 layer_lookup(sampler2D tex) {
    bool inside;
    vec2 uv = view_uv(pano_size, inside);
    return layer_lookup_at(tex, uv, inside);
}

vec4 layer_value() { return layer_lookup(layer); }
