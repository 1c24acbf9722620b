#version 330
// Distance from the light to the nearest object surface (composite.frag compares receivers with it).
in vec3 world_pos;
uniform vec3 light_pos;
out float out_distance;

void main() {
    out_distance = length(world_pos - light_pos);
}
