#version 430
// An empty dispatch (gl_passes.releasable.settle): Mesa's llvmpipe keeps the storage
// buffers and images last bound to the compute stage alive, released or not, until
// the next dispatch rebinds the stage.
layout(local_size_x = 1) in;

void main() {
}
