"""Predict's lighting methods, one module each, registered in :mod:`phyir.estimators` (entry-point group
``phyir.lighting_methods``).  Torch-free at import: each imports what it needs inside its function."""
