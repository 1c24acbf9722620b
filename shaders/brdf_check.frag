#version 330
// Test pass: brdf.glsl evaluated texel by texel (tests/test_insert_gl.py compares with phyir.brdf).
#include "brdf.glsl"

uniform sampler2D cosines_tex;   // (n.l, n.v, n.h, v.h)
uniform sampler2D material_tex;  // (B.r, B.g, B.b, R); metalness in material2_tex.r
uniform sampler2D material2_tex;
layout(location = 0) out vec4 out_diffuse;
layout(location = 1) out vec4 out_specular;

void main() {
    ivec2 ij = ivec2(gl_FragCoord.xy);
    vec4 c = texelFetch(cosines_tex, ij, 0);
    vec4 m = texelFetch(material_tex, ij, 0);
    vec3 fd, fs;
    brdf(c.x, c.y, c.z, c.w, m.rgb, m.a, texelFetch(material2_tex, ij, 0).r, fd, fs);
    out_diffuse = vec4(fd, 1.0);
    out_specular = vec4(fs, 1.0);
}
