#version 430 core
// Depth only (thesis Alg. 5 shadow maps): the fixed-function depth write is the output.
void main() {}
