#version 330
// Pass 1 of the layered path: the layer's linear values resampled into view pixels (RGBA32F).
#include "layer.glsl"
out vec4 out_value;

void main() { out_value = layer_value(); }
