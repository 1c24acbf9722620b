// Linear layer value -> display colour (used by display.frag and the one-pass view.frag).
// Chosen at compile time: KIND 0 HDR radiance, 1 colour in [0,1], 2 unit normal, 3 scalar;
// TONEMAP (HDR only) 0 sRGB (clamped), 1 ACES, 2 false colour.
#include "colour.glsl"
#ifndef KIND
#define KIND 0
#endif
#ifndef TONEMAP
#define TONEMAP 0
#endif

uniform float exposure;       // EV: values are scaled by 2^exposure ...
uniform float offset;         // ... then offset is added (HDR only)
uniform vec2 range;           // scalar: [lo, hi] mapped onto the colour map; false colour: log2 range
uniform sampler2D cmap;       // 256x1 colour map (scalar layers, false colour)
uniform vec3 background;
uniform int channel;          // HDR and colour layers: 0 RGB, 1 R, 2 G, 3 B, 4 luminance (shown as grey)

// s.rgb = linear value, s.a = panorama coverage (background where 0)
vec4 display_colour(vec4 s) {
    vec3 c = s.rgb;
#if KIND <= 1
    if (channel == 4) c = vec3(luminance(c));
    else if (channel > 0) c = vec3(c[channel - 1]);
#endif
#if KIND == 0
    c = c * exp2(exposure) + offset;
#if TONEMAP == 1
    vec3 rgb = srgb_encode(aces_fit(c));
#elif TONEMAP == 2
    vec3 rgb = colormap(cmap, (log2(max(luminance(c), 1e-12)) - range.x) / (range.y - range.x));
#else
    vec3 rgb = srgb_encode(c);
#endif
#elif KIND == 1
    vec3 rgb = srgb_encode(c);
#elif KIND == 2
    vec3 rgb = clamp(0.5 * c + 0.5, 0.0, 1.0);
#else
    vec3 rgb = colormap(cmap, (c.r - range.x) / (range.y - range.x));
#endif
    return vec4(mix(background, rgb, s.a), 1.0);
}
