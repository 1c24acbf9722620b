#version 330
// The viewer's draft insertion (viewer.insertion, Quality.composite_scale < 1): composite.frag with
// DRAFT 1 drew the receivers' kept share of their light into a low-resolution target; here it and
// the objects (their impostor tiles, looked up at full resolution: sharp edges while they move) go
// over the layer, so only the shadows and the light the objects block are coarser.
#include "layer.glsl"
#include "display.glsl"
#include "impostors.glsl"

uniform sampler2D draft_keep;    // rgb = the share of the receiver's light kept
uniform vec4 draft_rect;         // the region the target covers: (x, y, w, h), framebuffer pixels from the bottom
uniform vec2 draft_uv_scale;     // the part of the target the region fills (its size is rounded up)
out vec4 out_colour;

void main() {
    bool inside;
    vec2 uv = view_uv(pano_size, inside);
    vec4 bg = layer_lookup_at(layer, uv, inside);  // view_uv once
    vec2 st = (gl_FragCoord.xy - draft_rect.xy) / draft_rect.zw * draft_uv_scale;
    vec4 obj = objects_seen(uv_to_dir(uv, pano_size));  // outside the panorama bg.a = 0 hides it
    vec3 keep = texture(draft_keep, st).rgb;
    out_colour = display_colour(vec4(obj.rgb + (1.0 - obj.a) * bg.rgb * keep, bg.a));
}
