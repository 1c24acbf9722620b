"""Object insertion without GL: placement on surfaces, meshes and materials, views and pass files,
path-traced references."""
