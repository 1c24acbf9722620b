#version 330
// Evaluates the GLSL mapping functions once per pixel so tests/test_viewer_gl.py can compare them
// with phyir.pano.  Pixel positions are from the top-left (centres at +0.5) of a `size` target.
// MODE 0: uv_to_dir at pixel centres; 1: dir_to_uv of the directions in `dirs` (same texel);
// 2: perspective_dir of a view of `size` with persp = (fov_y, yaw, pitch).
#include "pano.glsl"
#ifndef MODE
#define MODE 0
#endif
uniform vec2 size;
uniform sampler2D dirs;
uniform vec3 persp;
out vec4 result;

void main() {
    vec2 px = vec2(gl_FragCoord.x, size.y - gl_FragCoord.y);
#if MODE == 0
    result = vec4(uv_to_dir(px, size), 0.0);
#elif MODE == 1
    result = vec4(dir_to_uv(texelFetch(dirs, ivec2(gl_FragCoord.xy), 0).xyz, size), 0.0, 0.0);
#else
    result = vec4(perspective_dir(px, size, persp.x, persp.y, persp.z), 0.0);
#endif
}
