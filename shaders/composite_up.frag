#version 330
// The viewer's draft insertion (viewer.insertion, Quality.composite_scale < 1): composite.frag with
// DRAFT 1 drew the objects (premultiplied radiance, coverage) and the receivers' kept share of their
// light into low-resolution targets; here they go over the layer at full resolution, so the
// panorama stays sharp while an object moves and only the objects and their shadows are coarser.
#include "layer.glsl"
#include "display.glsl"

uniform sampler2D draft_object;  // rgb = object radiance x coverage, a = coverage
uniform sampler2D draft_keep;    // rgb = the share of the receiver's light kept
uniform vec4 draft_rect;         // the region the targets cover: (x, y, w, h), framebuffer pixels from the bottom
uniform vec2 draft_uv_scale;     // the part of the targets the region fills (their sizes are rounded up)
out vec4 out_colour;

void main() {
    vec4 bg = layer_value();
    vec2 st = (gl_FragCoord.xy - draft_rect.xy) / draft_rect.zw * draft_uv_scale;
    vec4 obj = texture(draft_object, st);
    vec3 keep = texture(draft_keep, st).rgb;
    out_colour = display_colour(vec4(obj.rgb + (1.0 - obj.a) * bg.rgb * keep, bg.a));
}
