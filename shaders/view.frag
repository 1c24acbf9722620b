#version 330
// One-pass path (no linear passes registered): layer look-up and display transform together;
// with COMPARE > 0 against a reference image's layer (compare.glsl).
#ifndef COMPARE
#define COMPARE 0
#endif
#include "layer.glsl"
#include "display.glsl"
#if COMPARE > 0
#include "compare.glsl"
#endif
out vec4 out_colour;

void main() {
#if COMPARE > 0
    out_colour = compare_colour();
#else
    out_colour = display_colour(layer_value());
#endif
}
