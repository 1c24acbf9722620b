// Display transforms (tone maps and colour maps); numpy references in tests/test_viewer_gl.py.

float luminance(vec3 c) { return dot(c, vec3(0.2126, 0.7152, 0.0722)); }

// sRGB OETF of linear values clamped to [0, 1].
vec3 srgb_encode(vec3 c) {
    c = clamp(c, 0.0, 1.0);
    return mix(12.92 * c, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}

// Narkowicz's fit of the ACES filmic curve (display-linear), then sRGB.
vec3 aces_fit(vec3 x) {
    x = max(x, 0.0);
    return clamp((x * (2.51 * x + 0.03)) / (x * (2.43 * x + 0.59) + 0.14), 0.0, 1.0);
}

// 256-entry colour map look-up, linear between entries; t in [0, 1].
vec3 colormap(sampler2D lut, float t) {
    return texture(lut, vec2((clamp(t, 0.0, 1.0) * 255.0 + 0.5) / 256.0, 0.5)).rgb;
}
