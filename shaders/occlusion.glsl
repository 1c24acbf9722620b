// Occlusion by an inserted object's proxy spheres (phyir.insert.objects.fit_proxies): the share of a
// surface point's cosine-weighted hemisphere they cover (composite.frag for receivers, object.frag
// for the floor the object sees in its own reflections).
#include "pano.glsl"

// fraction of the cosine-weighted hemisphere a sphere covers (horizon-clipped form factor;
// Snyder 1996 / Lagarde & de Rousiers 2014), cos_t toward its centre, sin2_s = (r / d)^2
float sphere_form_factor(float cos_t, float sin2_s) {
    sin2_s = min(sin2_s, 0.9999);
    cos_t = clamp(cos_t, -1.0, 1.0);
    float sin_t = sqrt(max(1.0 - cos_t * cos_t, 1e-12));
    float e;
    if (cos_t * cos_t > sin2_s) {
        e = PI * sin2_s * max(cos_t, 0.0);
    } else {
        float x = sqrt(1.0 / sin2_s - 1.0);
        float y = clamp(-x * cos_t / sin_t, -1.0, 1.0);
        float sy = sin_t * sqrt(1.0 - y * y);
        e = (cos_t * acos(y) - x * sy) * sin2_s + atan(sy, x);
    }
    return clamp(e / PI, 0.0, 1.0);
}
