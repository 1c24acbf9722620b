#version 330
// Pass 2 of the layered path: linear values (pass 1 + linear passes) -> display colour.
#include "display.glsl"

uniform sampler2D hdr;        // linear values, same size as the viewport it is drawn into
uniform vec2 hdr_origin;      // framebuffer position of hdr's texel (0, 0) (bottom-left)
out vec4 out_colour;

void main() {
    out_colour = display_colour(texelFetch(hdr, ivec2(gl_FragCoord.xy - hdr_origin), 0));
}
