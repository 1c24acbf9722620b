"""Lighting from a panorama: projection probes, dominant lights, lighting at inserted objects."""
