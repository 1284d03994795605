"""moderngl GLSL passes on a headless EGL/OSMesa context (one context per render thread)."""
