"""The viewer's GL plumbing (ModernGL): surfaces (window / headless EGL), GLSL sources and the
program cache and uniform setters the renderers share."""
