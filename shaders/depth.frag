#version 330
// Depth-only pre-pass of an inserted object (with shadow.vert): the shading pass then runs once per pixel.
void main() {}
