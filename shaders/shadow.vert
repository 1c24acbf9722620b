#version 330
// Shadow map of an inserted object seen from one of its dominant lights.
in vec3 in_position;
uniform mat4 model;
uniform mat4 view_proj;   // world -> clip of the light's camera
out vec3 world_pos;

void main() {
    vec4 p = model * vec4(in_position, 1.0);
    world_pos = p.xyz;
    gl_Position = view_proj * p;
}
