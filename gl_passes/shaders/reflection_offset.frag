#version 430 core
// Reflection offset (thesis §5.4.2): the intermediate reflection image (Lr, r). A
// covered pixel is reliable: r >= 0 there (ray lengths), the clear value has r = -1.
in vec4 f_reflection;
layout(location = 0) out vec4 out_reflection;

void main() {
    out_reflection = f_reflection;
}
