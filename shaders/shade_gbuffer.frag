#version 330
// Test and diagnostic pass: the object shading of object.frag (ibl.glsl, probe only) applied to a
// G-buffer of normals and view vectors, one pixel per texel (tests/test_insert_gl.py compares it
// with phyir.render.shade_env).
#include "ibl.glsl"

uniform sampler2D gb_normal;   // unit normals, zero where there is no surface
uniform sampler2D gb_view;     // unit vectors toward the eye
uniform vec3 base_color;
uniform float roughness;
uniform float metallic;
out vec4 out_colour;

vec3 incoming(vec3 p, vec3 l, float lod) { return env_lod(l, lod); }
vec3 incoming_sharp(vec3 p, vec3 l) { return env_sharp(l); }

void main() {
    ivec2 ij = ivec2(gl_FragCoord.xy);
    vec3 n = texelFetch(gb_normal, ij, 0).xyz;
    vec3 v = texelFetch(gb_view, ij, 0).xyz;
    if (length(n) < 0.5 || dot(n, v) <= 0.0) {
        out_colour = vec4(0.0);
        return;
    }
    out_colour = vec4(shade_ibl(vec3(0.0), normalize(n), normalize(v), base_color, roughness, metallic), 1.0);
}
