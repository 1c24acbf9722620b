"""Geometry post-processing: what holds in any panorama from an upright camera, applied to a
network's depth and normals.

* :mod:`phyir.geometry.depth_normal` — the log-depth steps normals imply, and depth refined to
  follow them (predict; the training's depth–normal loss);
* :mod:`phyir.geometry.gravity` — normals near level or plumb pulled onto gravity's directions, and
  the floor under the camera continued into the nadir cap;
* :mod:`phyir.geometry.plausible` — GMNet's geometry made plausible and consistent before predict
  upsamples it (a collapsed normal head detected, the mirrored pass, the refinement, the floor).

Layer 0: these modules import only :mod:`phyir.pano` and torch.
"""
