#version 330
// One-pass path (no linear passes registered): layer look-up and display transform together.
#include "layer.glsl"
#include "display.glsl"
out vec4 out_colour;

void main() { out_colour = display_colour(layer_value()); }
