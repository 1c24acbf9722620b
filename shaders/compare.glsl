// The current layer against the same layer of a reference image (numpy mirror: viewer/compare.py).
// COMPARE (compile time): 1 difference a - b, 2 relative difference (a - b) / (|b| + 0.01),
// 3 squared error (a - b)^2 -- each reduced to one value and false-coloured -- and 4 split (the
// current image left of split_x, the reference right of it, both through display_colour).
// Needs layer.glsl and display.glsl (KIND, channel) first.
uniform sampler2D reference;      // the reference's layer, laid over the same panorama coordinates
uniform sampler2D compare_cmap;   // 256x1 colour map of the metric
uniform vec2 compare_range;       // metric values mapped onto [0, 1] of compare_cmap
uniform float split_x;            // split: view pixels from the left where the reference starts

const float REL_EPS = 0.01;
const vec3 SPLIT_LINE = vec3(0.9);

vec3 compare_metric(vec3 a, vec3 b) {
#if COMPARE == 1
    return a - b;
#elif COMPARE == 2
    return (a - b) / (abs(b) + REL_EPS);
#else
    vec3 d = a - b;
    return d * d;
#endif
}

// One value per pixel, as the display shows channels: scalar layers their channel, normals the
// mean, colour layers the mean, the chosen channel or the metric of the luminances.
float compare_value(vec3 a, vec3 b) {
#if KIND == 3
    return compare_metric(a, b).r;
#elif KIND == 2
    vec3 m = compare_metric(a, b);
    return (m.r + m.g + m.b) / 3.0;
#else
    if (channel == 4) return compare_metric(vec3(luminance(a)), vec3(luminance(b))).r;
    vec3 m = compare_metric(a, b);
    return channel > 0 ? m[channel - 1] : (m.r + m.g + m.b) / 3.0;
#endif
}

vec4 compare_colour() {
    vec4 a = layer_value();
#if COMPARE == 4
    float x = view_pixel().x;
    if (floor(x) == floor(split_x)) return vec4(SPLIT_LINE, 1.0);  // the line: the pixel split_x falls in
    return display_colour(x < split_x ? a : layer_lookup(reference));
#else
    vec4 b = layer_lookup(reference);
    float t = (compare_value(a.rgb, b.rgb) - compare_range.x) / (compare_range.y - compare_range.x);
    return vec4(mix(background, colormap(compare_cmap, t), a.a), 1.0);
#endif
}
