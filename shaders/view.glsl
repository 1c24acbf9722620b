// Screen pixel -> panorama coordinates for the two views (mirrored by phyir/insert/views.py).
// The view is chosen at compile time (VIEW_KIND: 0 = equirect pan/zoom, 1 = perspective
// look-around): software GL runs both sides of a run-time branch.
#ifndef VIEW_KIND
#define VIEW_KIND 0
#endif
uniform vec4 view_rect;       // (x, y, w, h) of the view in framebuffer pixels, y from the top
uniform float fb_height;      // framebuffer height: gl_FragCoord has its origin bottom-left
uniform vec2 eq_center;       // equirect: panorama coordinates shown at the view centre
uniform float eq_zoom;        // equirect: framebuffer pixels per panorama pixel
uniform vec3 persp;           // perspective: (fov_y [rad], yaw, pitch)

// Pixel position inside the view, from its top-left corner (pixel centres at +0.5).
vec2 view_pixel() {
    return vec2(gl_FragCoord.x - view_rect.x, (fb_height - gl_FragCoord.y) - view_rect.y);
}

// Panorama coordinates (u, v) seen at this fragment for a panorama of size (W, H);
// inside = false where the equirect view shows no panorama.
vec2 view_uv(vec2 size, out bool inside) {
    vec2 p = view_pixel();
#if VIEW_KIND == 0
    vec2 uv = eq_center + (p - 0.5 * view_rect.zw) / eq_zoom;
    inside = all(greaterThanEqual(uv, vec2(0.0))) && all(lessThan(uv, size));
    return uv;
#else
    inside = true;
    return dir_to_uv(perspective_dir(p, view_rect.zw, persp.x, persp.y, persp.z), size);
#endif
}
