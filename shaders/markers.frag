#version 330
// A coloured ring with a dark edge around each pinned probe, 1 px anti-aliased.
uniform float radius;
in vec2 offset_px;
flat in vec3 colour;
out vec4 out_colour;

void main() {
    float e = abs(length(offset_px) - radius);
    float ring = clamp(2.0 - e, 0.0, 1.0);
    float edge = clamp(3.5 - e, 0.0, 1.0);
    if (edge <= 0.0) discard;
    out_colour = vec4(colour * ring, edge);
}
