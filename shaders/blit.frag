#version 330
// Copy a texture 1:1 into the viewport (the renderer's cached view; glBlitFramebuffer is slow on
// software GL).  origin = framebuffer position of the texture's texel (0, 0).
uniform sampler2D src;
uniform vec2 origin;
out vec4 out_colour;

void main() { out_colour = texelFetch(src, ivec2(gl_FragCoord.xy - origin), 0); }
