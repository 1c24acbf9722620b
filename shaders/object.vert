#version 330
// Inserted object: world-space position and normal for the shading of object.frag.
in vec3 in_position;
in vec3 in_normal;
uniform mat4 model;          // local -> world
uniform mat3 normal_matrix;  // inverse transpose of model's 3x3
uniform mat4 view_proj;      // world -> clip of the camera drawing it
out vec3 world_pos;
out vec3 world_normal;

void main() {
    vec4 p = model * vec4(in_position, 1.0);
    world_pos = p.xyz;
    world_normal = normal_matrix * in_normal;
    gl_Position = view_proj * p;
}
