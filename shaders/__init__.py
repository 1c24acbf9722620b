"""GLSL shaders, shipped inside the wheel (importlib.resources.files("viewer.shaders"))."""
