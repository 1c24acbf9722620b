#version 330
// Overlay pass: one small quad per pinned-probe marker (instanced, no vertex buffer).
#define MAX_MARKERS 32
uniform vec2 marker_pos[MAX_MARKERS];    // pixels from the view's top-left corner
uniform vec3 marker_colour[MAX_MARKERS];
uniform float radius;                    // ring radius in framebuffer pixels
uniform vec2 view_size;                  // the viewport is the view rectangle
out vec2 offset_px;                      // from the marker centre
flat out vec3 colour;

void main() {
    vec2 corner = vec2(gl_VertexID & 1, (gl_VertexID >> 1) & 1) * 2.0 - 1.0;  // triangle strip
    offset_px = corner * (radius + 4.0);
    vec2 p = marker_pos[gl_InstanceID] + offset_px;
    colour = marker_colour[gl_InstanceID];
    gl_Position = vec4(p.x / view_size.x * 2.0 - 1.0, 1.0 - p.y / view_size.y * 2.0, 0.0, 1.0);
}
