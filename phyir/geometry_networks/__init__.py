"""Predict's geometry networks, one module each, registered in :mod:`phyir.estimators` (entry-point
group ``phyir.geometry_networks``).  Torch-free at import: each loads what it needs in ``load``."""
