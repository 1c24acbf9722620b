// Equirectangular mapping: a line-by-line mirror of phyir/pano.py (tested against it in
// tests/test_viewer_gl.py).  Continuous pixel coordinates (u along width, v along height),
// pixel centres at +0.5; size = (W, H).
const float PI = 3.14159265358979323846;

vec3 lonlat_to_dir(float lon, float lat) {
    float c = cos(lat);
    return vec3(c * sin(lon), sin(lat), -c * cos(lon));
}

vec2 dir_to_lonlat(vec3 d) {
    return vec2(atan(d.x, -d.z), atan(d.y, length(d.xz)));
}

vec3 uv_to_dir(vec2 uv, vec2 size) {
    return lonlat_to_dir(2.0 * PI * uv.x / size.x - PI, 0.5 * PI - PI * uv.y / size.y);
}

vec2 dir_to_uv(vec3 d, vec2 size) {
    vec2 ll = dir_to_lonlat(d);
    float u = mod((ll.x + PI) * (size.x / (2.0 * PI)), size.x);
    return vec2(u, (0.5 * PI - ll.y) * (size.y / PI));
}

// pano.perspective_dirs: pinhole camera at the origin looking along -z at yaw = pitch = 0;
// px = pixel position from the view's top-left corner (centres at +0.5), view = (width, height);
// yaw > 0 turns toward +x, pitch > 0 looks up.
vec3 perspective_dir(vec2 px, vec2 view, float fov_y, float yaw, float pitch) {
    float f = 0.5 * view.y / tan(0.5 * fov_y);
    vec3 d = normalize(vec3((px.x - 0.5 * view.x) / f, (0.5 * view.y - px.y) / f, -1.0));
    float cp = cos(pitch), sp = sin(pitch);
    d = vec3(d.x, cp * d.y - sp * d.z, sp * d.y + cp * d.z);
    float cy = cos(-yaw), sy = sin(-yaw);  // yaw_matrix(-yaw)
    return vec3(cy * d.x + sy * d.z, d.y, -sy * d.x + cy * d.z);
}
