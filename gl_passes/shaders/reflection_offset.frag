#version 430 core
// Reflection offset (thesis §5.4.2): the intermediate reflection image (Lr, r) and
// its reliability (1 where a kept triangle or sample covers the pixel; cleared to 0).
in vec4 f_reflection;
layout(location = 0) out vec4 out_reflection;
layout(location = 1) out float out_reliable;

void main() {
    out_reflection = f_reflection;
    out_reliable = 1.0;
}
