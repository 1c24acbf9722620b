"""The rendering layer: the UE4 BRDF, Monte Carlo sampling, the renderer and the split sum."""
